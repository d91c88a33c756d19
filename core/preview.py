"""A contact sheet of a sequence: a few frames as rows of RGB | depth | flow | mask, in one PNG.

``deepslam render --preview PNG`` writes one after rendering; :func:`write_contact_sheet` makes one from any
folder :func:`deepslam.core.readers.open_sequence` opens, showing only what the sequence has (real KITTI:
the images alone). Colours: :mod:`deepslam.core.colorize` (depth near bright, flow on the Middlebury wheel,
one colour per moving instance over the dimmed image).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np

from deepslam.core import atomic
from deepslam.core.colorize import depth_range_m, depth_to_rgb, flow_magnitude_scale, flow_to_rgb, mask_to_rgb
from deepslam.core.errors import InputError
from deepslam.core.outputs import check_output_not_input
from deepslam.core.readers import open_sequence
from deepslam.core.sequence import Sequence


@dataclasses.dataclass(frozen=True)
class ContactSheetConfig:
    """What a contact sheet shows and how large."""

    rows: int = 6
    """Most frames shown, evenly spaced over the sequence (over the frames that have flow, where it has flow)."""
    panel_width_px: int = 320
    """Width of each panel in pixels; images are scaled to it (never up), keeping their aspect."""

    def validate(self) -> "ContactSheetConfig":
        if self.rows < 1:
            raise InputError(None, f"a contact sheet needs at least one row, got {self.rows}")
        if self.panel_width_px < 32:
            raise InputError(None, f"panel width must be at least 32 px, got {self.panel_width_px}")
        return self


_LABEL_H = 18
"""Height in pixels of the strip holding the column titles."""


def sheet_frames(seq: Sequence, rows: int) -> np.ndarray:
    """(K,) int64 frame indices, K <= ``rows``: evenly spaced from the first to the last frame that has forward
    flow (every frame but the last, where the sequence has flow), else to the last frame."""
    n = len(seq)
    last = n - 2 if seq.flow_paths is not None and n > 1 else n - 1
    return np.unique(np.round(np.linspace(0, last, min(rows, last + 1))).astype(np.int64))


def _label(img: np.ndarray, text: str, org: tuple[int, int], max_width: int) -> None:
    """Draw ``text`` on ``img`` (uint8 RGB, in place) at ``org`` (x, y of the baseline), white on a black outline,
    smaller or cut so that it fits in ``max_width`` pixels."""
    scale = 0.4
    while cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] > max_width and len(text) > 1:
        if scale > 0.3:
            scale -= 0.05
        else:
            text = text[:-1]
    for colour, thick in (((0, 0, 0), 3), ((255, 255, 255), 1)):
        cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)


def _fit(img: np.ndarray, width: int, height: int, nearest: bool = False) -> np.ndarray:
    """``img`` (H, W[, 3]) uint8 as (height, width, 3) RGB (grey repeated)."""
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.shape[:2] != (height, width):
        img = cv2.resize(img, (width, height), interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)
    return np.ascontiguousarray(img)


def contact_sheet(seq: Sequence, config: ContactSheetConfig = ContactSheetConfig()) -> np.ndarray:
    """The contact sheet of ``seq`` as an image.

    Columns: RGB (always), depth (where the sequence has depth; near bright, one range for all rows, given in
    the title), flow (forward flow on the Middlebury colour wheel, each row fully saturated at the length
    written on it: :func:`deepslam.core.colorize.flow_magnitude_scale`), mask (instance ids over the dimmed
    image). A frame lacking a column's data (the last frame's flow) shows a grey panel.

    Returns:
        (rows * h + 18, columns * w, 3) uint8 RGB, h x w the panel size (the image scaled to
        ``panel_width_px``, never up).
    """
    config.validate()
    frames = sheet_frames(seq, config.rows)
    cam = seq.camera
    w = min(config.panel_width_px, cam.width)
    h = max(1, int(round(cam.height * w / cam.width)))
    images = [seq.image(int(i)) for i in frames]
    depths = [seq.depth(int(i)) for i in frames] if seq.depth_paths is not None else None
    flows = [seq.flow(int(i)) for i in frames] if seq.flow_paths is not None else None
    masks = [seq.mask(int(i)) for i in frames] if seq.mask_paths is not None else None

    columns: list[tuple[str, list[np.ndarray | None]]] = [("RGB", [_fit(im, w, h) for im in images])]
    if depths is not None:
        near, far = depth_range_m(np.concatenate([d.ravel() for d in depths]))
        columns.append((f"depth {near:.1f}-{far:.0f} m",
                        [_fit(depth_to_rgb(d, near, far), w, h, nearest=True) for d in depths]))
    flow_scales: list[float | None] = []
    flow_column = len(columns)
    if flows is not None:
        flow_scales = [None if f is None else flow_magnitude_scale(f) for f in flows]
        columns.append(("flow (colour wheel)", [None if f is None else _fit(flow_to_rgb(f, s), w, h, nearest=True)
                                                for f, s in zip(flows, flow_scales)]))
    if masks is not None:
        columns.append(("mask",
                        [_fit(mask_to_rgb(m, im), w, h, nearest=True) for m, im in zip(masks, images)]))

    sheet = np.full((_LABEL_H + len(frames) * h, len(columns) * w, 3), 24, np.uint8)
    for c, (title, panels) in enumerate(columns):
        _label(sheet, title, (c * w + 4, _LABEL_H - 5), w - 8)
        for r, panel in enumerate(panels):
            y = _LABEL_H + r * h
            if panel is None:
                sheet[y:y + h, c * w:(c + 1) * w] = 96
                _label(sheet, "none", (c * w + 4, y + 14), w - 8)
            else:
                sheet[y:y + h, c * w:(c + 1) * w] = panel
    for r, i in enumerate(frames):
        _label(sheet, f"frame {int(i)}  t={float(seq.timestamps_s[i]):.2f} s", (4, _LABEL_H + r * h + 14), w - 8)
        if flow_scales and flow_scales[r] is not None:
            _label(sheet, f"{flow_scales[r]:.2g} px", (flow_column * w + 4, _LABEL_H + r * h + 14), w - 8)
    return sheet


def check_sheet_path(png: str | Path, inputs: list[tuple[str, str | Path | None]]) -> None:
    """InputError naming ``png`` unless it is a file name ending in .png that is not, nor lies inside, one of
    ``inputs`` ((flag, path) pairs: the sequence folder it shows, a render's --out, a scene file)."""
    png = Path(png)
    if png.suffix.lower() != ".png":
        raise InputError(png, "the contact sheet is a PNG: give a file name ending in .png")
    if png.is_dir():
        raise InputError(png, "is a folder, expected a .png file name")
    where = png.expanduser().resolve()
    for flag, inp in inputs:  # also an input not written yet (a render's --out)
        if inp is not None and str(inp) != "":
            folder = Path(inp).expanduser().resolve()
            if where == folder or folder in where.parents:
                raise InputError(png, f"the contact sheet would be written into {flag} ({inp}); "
                                      "choose a file outside it")
    check_output_not_input(png, inputs, "the contact sheet")


def write_contact_sheet(sequence: str | Path | Sequence, png: str | Path,
                        config: ContactSheetConfig = ContactSheetConfig()) -> Path:
    """Write the :func:`contact_sheet` of a sequence (a folder :func:`open_sequence` opens, or an open
    :class:`Sequence`) to ``png``, atomically; refused (InputError) where ``png`` is not a .png name or lies
    inside the sequence folder.

    Returns:
        ``png`` as a Path.
    """
    seq = sequence if isinstance(sequence, Sequence) else open_sequence(sequence)
    check_sheet_path(png, [("sequence", seq.root)])
    atomic.write_png(png, contact_sheet(seq, config))
    return Path(png)
