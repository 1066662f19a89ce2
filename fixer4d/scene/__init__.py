"""fixer4d.scene"""
