"""chizu numeric plugins: world model, simulator and the methods' numerics.

Pure numpy/scipy (and pydantic for the world description); never imports
``service`` or pyswip.
"""
