"""VO model files: writing and reading networks as safetensors files (:mod:`vo.modelfiles.modelio`), where
things sit in their tree without torch (:mod:`vo.modelfiles.modeltree`), the models shipped in ``models/``
(:mod:`vo.modelfiles.models`) and the conversion of old pickle files (:mod:`vo.modelfiles.convert`)."""
