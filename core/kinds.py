"""The camera kind of a sequence: the one rule that picks shipped models (``vo``, ``slam``) and the
pose graph's place-recognition defaults (``slam.reloc.RelocConfig.for_kind``).

Kinds: ``kitti`` (street cameras, wide), ``euroc`` (indoor MAV cameras), ``tum`` (640x480 hand-held RGB-D).
"""
from __future__ import annotations

KINDS = ("kitti", "euroc", "tum")
"""Camera kinds with a shipped model: KITTI-like street cameras, EuRoC-like MAV cameras, and 640x480
hand-held RGB-D cameras (TUM RGB-D)."""


def kind_for_scene(scene: str) -> str:
    """The kind of a simulated scene by name: street, city, road -> ``kitti``; room, indoor, office ->
    ``euroc``; ``""`` for a name that says neither."""
    scene = scene.lower()
    if any(w in scene for w in ("street", "city", "road", "kitti")):
        return "kitti"
    if any(w in scene for w in ("room", "indoor", "euroc", "office")):
        return "euroc"
    return ""


def kind_for_sequence(seq) -> str:
    """The kind of a sequence: its reader's kind for KITTI/EuRoC/TUM; for our format the scene's kind when
    ``sequence.json`` names one (:func:`kind_for_scene`), else by the image's aspect ratio (wider than
    2:1 -> ``kitti``, else ``euroc``)."""
    if seq.kind in KINDS:
        return seq.kind
    scene = str(seq.meta.get("scene", "")) if isinstance(seq.meta, dict) else ""
    return kind_for_scene(scene) or ("kitti" if seq.camera.width > 2 * seq.camera.height else "euroc")
