"""fixer4d.init"""
