"""A BoW vocabulary trained once and reused: loaded from its file when that file was saved for the same
inputs (recorded in its meta), else trained on the SIFT descriptors of given images and saved."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import numpy as np

from deepslam.core.errors import InputError
from deepslam.slam.reloc import FeatureExtractor, RelocConfig, Vocabulary, train_vocabulary


def cached_vocabulary(path: str | Path, meta: dict, images: Iterable[np.ndarray], reloc: RelocConfig,
                      rng: np.random.Generator) -> Vocabulary | None:
    """The vocabulary at ``path`` when its saved meta holds every item of ``meta``; else one trained on
    the SIFT descriptors (``reloc``'s extractor, ``reloc.vocabulary_size`` words, ``rng``) of ``images``
    (uint8 grey or RGB, consumed only when training) and saved to ``path`` with ``meta``. None when the
    images have no keypoints (nothing is saved). An unreadable file there is replaced."""
    path = Path(path)
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                saved = json.loads(str(z["meta"]))
            if isinstance(saved, dict) and all(saved.get(k) == v for k, v in meta.items()):
                return Vocabulary.load(path)
        except (InputError, OSError, ValueError, KeyError):
            pass
    extract = FeatureExtractor(reloc)
    descs = [d for d in (extract(image).descriptors for image in images) if len(d)]
    if not descs:
        return None
    vocabulary = train_vocabulary(descs, reloc.vocabulary_size, rng)
    vocabulary.save(path, meta=meta)
    return vocabulary
