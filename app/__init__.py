"""fixer4d-view: the desktop viewer/editor for spacetime Gaussian scenes (docs/design.md §16).

The viewer imports fixer4d; fixer4d never imports app. Models reach the viewer as raw parameter
arrays (``app.gaussians.GaussianArrays``) and render functions are injected, so the UI never
touches a model's internals.
"""
