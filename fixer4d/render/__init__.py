"""fixer4d.render"""
