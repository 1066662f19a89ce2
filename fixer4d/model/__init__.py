"""fixer4d.model"""
