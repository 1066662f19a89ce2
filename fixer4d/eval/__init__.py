"""fixer4d.eval"""
