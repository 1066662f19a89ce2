"""fixer4d.restore"""
