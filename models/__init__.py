"""The models this project ships (package data: ``*.safetensors``, ``motion/*.json``; see README.md).

Installed, this folder is ``deepslam.models``; :func:`deepslam.vo.models.models_dir` finds it.
"""
