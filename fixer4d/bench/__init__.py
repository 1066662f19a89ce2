"""fixer4d.bench"""
