"""fixer4d.train"""
