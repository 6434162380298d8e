"""Vysics: simulation-ready object models from short RGBD robot-interaction sessions.

``service`` holds the science and the data. It never imports fastapi or prefect.
Each science stage is one subpackage with one entry point ``run(inputs, cfg, *, progress=None)``.
"""

__version__ = "0.1.0"
