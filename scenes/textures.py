"""Procedural textures, generated at build time from a ``numpy.random.Generator``.

Every painter has the signature ``painter(h_px, w_px, px_per_m, rng) -> uint8 (h_px, w_px, 3) RGB`` (row 0
is the top of the surface as a viewer sees it) and draws only from the generator it is given, so the
same seed gives the same bytes. The textures are rich and non-repetitive on purpose (multi-scale
noise, bricks, windows, signs with text, posters, stains) so that DIS optical flow and SIFT find
structure everywhere.
"""
from __future__ import annotations

import string
from typing import Callable

import cv2
import numpy as np

_CV_MAJOR = int(cv2.__version__.split(".")[0])
"""OpenCV's major version: 5 and later draw text on 8-bit images only."""

Painter = Callable[[int, int, float, np.random.Generator], np.ndarray]

_WORDS = ["CAFE", "BAR", "HOTEL", "PHARMACY", "BAKERY", "BOOKS", "SHOES", "BANK", "POST", "PIZZA",
          "TAXI", "MARKET", "DELI", "GARAGE", "OPTIC", "FLOWERS", "SUSHI", "KEBAB", "HAIR", "MUSIC",
          "TOYS", "SPORT", "PHOTO", "LAUNDRY", "GALLERY", "DENTIST", "TAILOR", "KIOSK", "TEA", "WINE"]


# ----------------------------------------------------------------------------------------------
# building blocks
# ----------------------------------------------------------------------------------------------

def value_noise(h: int, w: int, cell_px: float, rng: np.random.Generator) -> np.ndarray:
    """Smooth value noise in [0, 1], float32 (h, w), features about ``cell_px`` pixels across."""
    cell_px = max(float(cell_px), 1.0)
    gh = int(np.ceil(h / cell_px)) + 3
    gw = int(np.ceil(w / cell_px)) + 3
    grid = rng.random((gh, gw), dtype=np.float32)
    big = cv2.resize(grid, (int(gw * cell_px), int(gh * cell_px)), interpolation=cv2.INTER_CUBIC)
    oy = int(cell_px)
    ox = int(cell_px)
    out = big[oy:oy + h, ox:ox + w]
    if out.shape != (h, w):  # tiny sizes
        out = cv2.resize(grid, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.clip(out, 0.0, 1.0)


def fbm(h: int, w: int, cell_px: float, rng: np.random.Generator, octaves: int = 4,
        gain: float = 0.5) -> np.ndarray:
    """Fractal (multi-octave) noise in about [0, 1], float32 (h, w); finest octave >= 1 px."""
    out = np.zeros((h, w), np.float32)
    amp, total, cell = 1.0, 0.0, float(cell_px)
    for _ in range(octaves):
        out += amp * value_noise(h, w, cell, rng)
        total += amp
        amp *= gain
        cell = max(cell / 2.0, 1.0)
    return out / total


def colour_jitter(rgb, rng: np.random.Generator, amount: float = 0.12) -> np.ndarray:
    base = np.asarray(rgb, np.float32)
    return np.clip(base * (1.0 + rng.uniform(-amount, amount, 3)), 0, 255)


def _modulate(img: np.ndarray, noise: np.ndarray, strength: float) -> np.ndarray:
    return img * (1.0 - strength + 2.0 * strength * noise)[..., None]


def _to_u8(img: np.ndarray) -> np.ndarray:
    return np.clip(img, 0, 255).astype(np.uint8)


def _rand_text(rng: np.random.Generator, n: int) -> str:
    chars = string.ascii_uppercase + string.digits
    return "".join(chars[i] for i in rng.integers(0, len(chars), n))


def put_text_box(img: np.ndarray, x0: int, y0: int, x1: int, y1: int, text: str, fg, bg) -> None:
    """Draw a sign: a filled rectangle with centred text fitted to it (in place, float32 RGB)."""
    h, w = img.shape[:2]
    x0, x1 = max(0, x0), min(w, x1)
    y0, y1 = max(0, y0), min(h, y1)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return
    img[y0:y1, x0:x1] = bg
    bw, bh = x1 - x0, y1 - y0
    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, th), _ = cv2.getTextSize(text, font, 1.0, 2)
    scale = min(0.85 * bw / max(tw, 1), 0.7 * bh / max(th, 1))
    if scale * th < 3:
        return
    thick = max(1, int(round(scale * 2)))
    (tw, th), _ = cv2.getTextSize(text, font, scale, thick)
    org = (x0 + (bw - tw) // 2, y0 + (bh + th) // 2)
    if img.dtype == np.uint8 or _CV_MAJOR < 5:
        cv2.putText(img, text, org, font, scale, tuple(float(c) for c in fg), thick, cv2.LINE_AA)
    else:  # OpenCV 5 draws text on 8-bit images only: its anti-aliased coverage, blended in
        box = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.putText(box, text, (org[0] - x0, org[1] - y0), font, scale, 255, thick, cv2.LINE_AA)
        a = (box.astype(np.float32) / 255.0)[..., None]
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1.0 - a) + np.asarray(fg, np.float32) * a


def _blobs(img: np.ndarray, rng: np.random.Generator, n: int, size_px: float, alpha: float) -> None:
    """Stains / graffiti: soft random blobs in random colours, in place."""
    h, w = img.shape[:2]
    for _ in range(n):
        r = max(1.0, rng.uniform(0.3, 1.0) * size_px)
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        x0, x1 = int(max(0, cx - r)), int(min(w, cx + r + 1))
        y0, y1 = int(max(0, cy - r)), int(min(h, cy + r + 1))
        if x1 <= x0 or y1 <= y0:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1]
        m = np.clip(1.0 - ((xx - cx) ** 2 + (yy - cy) ** 2) / (r * r), 0, 1) ** 0.7 * alpha
        col = rng.uniform(0, 255, 3).astype(np.float32)
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - m[..., None]) + col * m[..., None]


def poster(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A poster/advert: coloured background, shapes and text. float32 (h, w, 3)."""
    img = np.empty((h, w, 3), np.float32)
    img[:] = rng.uniform(30, 230, 3)
    for _ in range(int(rng.integers(2, 6))):
        col = tuple(float(c) for c in rng.uniform(0, 255, 3))
        if rng.random() < 0.5:
            c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
            cv2.circle(img, c, max(1, int(rng.uniform(0.1, 0.4) * min(h, w))), col, -1, cv2.LINE_AA)
        else:
            p = rng.uniform(0, 1, (3, 2)) * [w, h]
            cv2.fillPoly(img, [p.astype(np.int32)], col, cv2.LINE_AA)
    if h >= 8:
        put_text_box(img, 0, int(0.7 * h), w, h, _rand_text(rng, int(rng.integers(3, 7))),
                     rng.uniform(0, 255, 3), rng.uniform(0, 255, 3))
    return img


# ----------------------------------------------------------------------------------------------
# surface painters
# ----------------------------------------------------------------------------------------------

def plaster(base_rgb) -> Painter:
    def paint(h, w, ppm, rng):
        col = colour_jitter(base_rgb, rng)
        img = np.empty((h, w, 3), np.float32)
        img[:] = col
        img = _modulate(img, fbm(h, w, 2.0 * ppm, rng, 5), 0.18)
        _blobs(img, rng, int(2 + h * w / (ppm * ppm * 8)), 0.6 * ppm, 0.25)
        return _to_u8(img)
    return paint


def bricks(base_rgb, brick_m=(0.5, 0.2)) -> Painter:
    """Large bricks / stone blocks with mortar, per-brick colour jitter and dirt."""
    def paint(h, w, ppm, rng):
        bw = max(4.0, brick_m[0] * ppm)
        bh = max(3.0, brick_m[1] * ppm)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        row = np.floor(yy / bh)
        xs = xx + (row % 2) * bw * 0.5
        col = np.floor(xs / bw)
        nrows, ncols = int(row.max()) + 1, int(col.max()) + 2
        jitter = rng.uniform(0.75, 1.2, (nrows, ncols)).astype(np.float32)
        hue = rng.uniform(-12, 12, (nrows, ncols, 3)).astype(np.float32)
        base = np.asarray(colour_jitter(base_rgb, rng, 0.08), np.float32)
        img = base * jitter[row.astype(int), col.astype(int)][..., None] + hue[row.astype(int), col.astype(int)]
        mortar = ((yy % bh) < 1.0) | ((xs % bw) < 1.0)
        img[mortar] = (170, 165, 155)
        img = _modulate(img, fbm(h, w, 1.5 * ppm, rng, 4), 0.15)
        _blobs(img, rng, int(1 + h * w / (ppm * ppm * 10)), 0.8 * ppm, 0.2)
        return _to_u8(img)
    return paint


def panels(base_rgb) -> Painter:
    """Metal/concrete cladding panels of random widths with seams and streaks."""
    def paint(h, w, ppm, rng):
        img = np.empty((h, w, 3), np.float32)
        img[:] = colour_jitter(base_rgb, rng)
        x = 0
        while x < w:
            pw = int(max(3, rng.uniform(0.8, 2.5) * ppm))
            img[:, x:x + pw] *= rng.uniform(0.85, 1.15)
            img[:, x:x + 1] *= 0.6
            x += pw
        y = 0
        while y < h:
            ph = int(max(3, rng.uniform(1.0, 3.0) * ppm))
            img[y:y + 1] *= 0.6
            y += ph
        streak = cv2.resize(rng.random((2, max(2, w // 3)), dtype=np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
        img = _modulate(img, 0.6 * streak + 0.4 * fbm(h, w, ppm, rng, 4), 0.15)
        return _to_u8(img)
    return paint


def facade(rng_style: np.random.Generator) -> Painter:
    """A building facade: wall material, floors of windows (each different), a ground floor with
    shop windows, doors and signs, posters and graffiti. ``rng_style`` fixes the building's style."""
    wall_kind = int(rng_style.integers(0, 3))
    wall_rgb = rng_style.uniform(90, 230, 3)
    floor_m = rng_style.uniform(2.9, 3.6)
    win_w_m = rng_style.uniform(0.9, 1.6)
    win_h_m = rng_style.uniform(1.2, 1.9)
    spacing_m = win_w_m + rng_style.uniform(0.8, 2.2)
    frame_rgb = rng_style.uniform(20, 250, 3)
    shop = rng_style.random() < 0.75

    wall = [plaster(wall_rgb), bricks(wall_rgb * np.array([1.0, 0.6, 0.45])), panels(wall_rgb)][wall_kind]

    def paint(h, w, ppm, rng):
        img = wall(h, w, ppm, rng).astype(np.float32)
        floor_px = floor_m * ppm
        n_floors = int(h / floor_px)
        ww, wh = max(2, int(win_w_m * ppm)), max(2, int(win_h_m * ppm))
        sp = spacing_m * ppm
        n_cols = max(1, int((w - sp * 0.3) / sp))
        margin = (w - n_cols * sp) / 2.0
        ground = 1 if shop else 0
        for f in range(ground, n_floors):
            y_bottom = h - f * floor_px - 0.35 * floor_px
            y0 = int(y_bottom - wh)
            if y0 < 2:
                continue
            for c in range(n_cols):
                if rng.random() < 0.07:
                    continue  # a wall where a window would be: breaks repetition
                x0 = int(margin + c * sp + (sp - ww) / 2 + rng.normal(0, 0.03 * ppm))
                _window(img, x0, y0, ww, wh, frame_rgb, rng, ppm)
        if shop and h > floor_px:
            _ground_floor(img, h, w, floor_px, ppm, rng)
        elif h > 0.3 * floor_px:
            # plain ground floor: a door and a plinth
            img[int(h - 0.4 * ppm):] *= 0.7
            x0 = int(rng.uniform(0.1, 0.8) * w)
            _door(img, x0, h, int(1.1 * ppm), int(2.2 * ppm), rng)
        for _ in range(int(rng.poisson(w / (8.0 * ppm)))):
            ph, pw = int(rng.uniform(0.6, 1.4) * ppm), int(rng.uniform(0.4, 1.0) * ppm)
            x0, y0 = int(rng.uniform(0, max(1, w - pw))), int(h - rng.uniform(1.0, 2.4) * ppm)
            if ph > 3 and pw > 3 and 0 <= y0 and y0 + ph <= h:
                img[y0:y0 + ph, x0:x0 + pw] = poster(ph, pw, rng)[: ph, : pw]
        _blobs(img[int(h - 2.5 * ppm):], rng, int(rng.poisson(w / (10.0 * ppm))), 0.7 * ppm, 0.5)
        # cornice lines between floors
        for f in range(1, n_floors + 1):
            y = int(h - f * floor_px)
            if 0 <= y < h:
                img[y:y + max(1, int(0.12 * ppm))] *= 0.75
        return _to_u8(img)
    return paint


def _window(img, x0, y0, ww, wh, frame_rgb, rng, ppm):
    h, w = img.shape[:2]
    x1, y1 = min(w, x0 + ww), min(h, y0 + wh)
    x0, y0 = max(0, x0), max(0, y0)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return
    img[y0:y1, x0:x1] = frame_rgb
    fr = max(1, int(0.08 * ppm))
    gx0, gy0, gx1, gy1 = x0 + fr, y0 + fr, x1 - fr, y1 - fr
    if gx1 <= gx0 or gy1 <= gy0:
        return
    gh, gw = gy1 - gy0, gx1 - gx0
    # glass: sky reflection gradient + noise, sometimes a curtain or a lit room
    t = np.linspace(0, 1, gh, dtype=np.float32)[:, None, None]
    top = rng.uniform(60, 200, 3)
    bottom = rng.uniform(10, 90, 3)
    glass = top * (1 - t) + bottom * t + np.zeros((1, gw, 1), np.float32)
    glass = _modulate(glass, value_noise(gh, gw, max(2.0, 0.3 * ppm), rng), 0.25)
    kind = rng.random()
    if kind < 0.3:
        cw = int(gw * rng.uniform(0.3, 0.6))
        glass[:, :cw] = colour_jitter(rng.uniform(80, 240, 3), rng) * (0.8 + 0.2 * value_noise(gh, cw, 2, rng))[..., None] if cw > 0 else glass[:, :cw]
    elif kind < 0.4:
        glass[:] = rng.uniform(180, 255, 3) * (0.85 + 0.15 * value_noise(gh, gw, 3, rng))[..., None]
    img[gy0:gy1, gx0:gx1] = glass
    # mullions
    if gw > 6:
        mx = gx0 + gw // 2
        img[gy0:gy1, mx:mx + max(1, fr // 2 + 1)] = frame_rgb
    if gh > 8 and rng.random() < 0.6:
        my = gy0 + int(gh * rng.uniform(0.25, 0.4))
        img[my:my + max(1, fr // 2 + 1), gx0:gx1] = frame_rgb
    # sill
    sy = min(h - 1, y1)
    img[sy:sy + max(1, int(0.1 * ppm)), max(0, x0 - fr):min(w, x1 + fr)] *= 0.55


def _door(img, x0, h, dw, dh, rng):
    w = img.shape[1]
    x1 = min(w, x0 + dw)
    y0 = max(0, h - dh)
    if x1 - x0 < 2:
        return
    img[y0:h, x0:x1] = colour_jitter(rng.uniform(20, 160, 3), rng)
    img[y0:h, x0:x0 + 1] *= 0.5
    img[y0:y0 + 1, x0:x1] *= 0.5
    kx = int(x0 + 0.8 * (x1 - x0))
    ky = int(h - 0.45 * dh)
    img[ky:ky + 2, kx:kx + 2] = 220


def _ground_floor(img, h, w, floor_px, ppm, rng):
    gf0 = int(h - floor_px)
    x = int(rng.uniform(0.2, 1.0) * ppm)
    while x < w - ppm:
        sw = int(rng.uniform(2.5, 6.0) * ppm)
        x1 = min(w - int(0.3 * ppm), x + sw)
        if x1 - x < ppm:
            break
        # sign band
        sy0 = gf0 + int(0.1 * floor_px)
        sy1 = sy0 + max(3, int(0.6 * ppm))
        word = _WORDS[int(rng.integers(0, len(_WORDS)))]
        if rng.random() < 0.4:
            word += " " + str(int(rng.integers(1, 99)))
        put_text_box(img, x, sy0, x1, sy1, word, rng.uniform(0, 255, 3), rng.uniform(0, 255, 3))
        # shop window + door
        wy0 = sy1 + int(0.2 * ppm)
        dw = int(1.0 * ppm)
        if rng.random() < 0.5:
            _door(img, x, h, dw, h - wy0, rng)
            wx0 = x + dw + 1
        else:
            wx0 = x
        if x1 - wx0 > 3 and h - int(0.4 * ppm) - wy0 > 3:
            gh, gw = h - int(0.4 * ppm) - wy0, x1 - wx0
            t = np.linspace(0, 1, gh, dtype=np.float32)[:, None, None]
            glass = rng.uniform(80, 200, 3) * (1 - t) + rng.uniform(10, 70, 3) * t + np.zeros((1, gw, 1), np.float32)
            img[wy0:wy0 + gh, wx0:x1] = _modulate(glass, value_noise(gh, gw, max(2, 0.5 * ppm), rng), 0.3)
            # goods on display: random small boxes
            for _ in range(int(rng.integers(2, 8))):
                bw, bh = int(rng.uniform(0.1, 0.5) * ppm) + 1, int(rng.uniform(0.1, 0.6) * ppm) + 1
                bx = int(rng.uniform(wx0, max(wx0 + 1, x1 - bw)))
                by = int(wy0 + gh - bh - rng.uniform(0, 0.3) * gh)
                img[max(0, by):by + bh, bx:bx + bw] = rng.uniform(0, 255, 3)
        x = x1 + int(rng.uniform(0.3, 1.5) * ppm)


def asphalt(h, w, ppm, rng):
    img = np.empty((h, w, 3), np.float32)
    img[:] = colour_jitter((78, 78, 82), rng, 0.06)
    img = _modulate(img, fbm(h, w, 3.0 * ppm, rng, 6), 0.22)
    grain = rng.random((h, w), dtype=np.float32)
    img = _modulate(img, grain, 0.10)
    _patches_and_cracks(img, ppm, rng)
    return img  # float32: roads add markings before conversion


GRAINY_ASPHALT_CONTRAST = (0.10, 0.45)
"""Range of the grainy asphalt's texture contrast (relative std of its 6-25 cm and texel-scale
texture), drawn per road stretch: DIS reads a road's motion only as far as its texture lets it."""


def asphalt_grainy(h, w, ppm, rng):
    """Asphalt with visible grain: :func:`asphalt`'s near-uniform surface (what DIS reads as a third of
    its true motion on a render, against half on KITTI's real roads) replaced by a tone drawn in
    70-130 grey levels, metre-scale blotches (10 %) and texture at 6-25 cm and at the texel (the
    contrast drawn from :data:`GRAINY_ASPHALT_CONTRAST`); patches and cracks as in :func:`asphalt`.
    Float32 (h, w, 3) RGB, 0-255 before clipping."""
    def unit(n: np.ndarray) -> np.ndarray:
        return (n - n.mean()) / (n.std() + 1e-6)

    contrast = float(rng.uniform(*GRAINY_ASPHALT_CONTRAST))
    tone = float(rng.uniform(70.0, 130.0))
    img = np.empty((h, w, 3), np.float32)
    img[:] = colour_jitter((tone, tone, 1.03 * tone), rng, 0.04)
    blotches = unit(fbm(h, w, 2.5 * ppm, rng, 3))
    mid = unit(fbm(h, w, 0.25 * ppm, rng, 3))
    grain = unit(cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 0.7))
    img *= np.clip(1.0 + 0.10 * blotches + contrast * (0.6 * mid + 0.4 * grain), 0.3, 1.8)[..., None]
    _patches_and_cracks(img, ppm, rng)
    return img  # float32: roads add markings before conversion


def _patches_and_cracks(img: np.ndarray, ppm: float, rng: np.random.Generator) -> None:
    """Darker and lighter rectangular patches and thin dark cracks, in place."""
    h, w = img.shape[:2]
    for _ in range(int(rng.poisson(h * w / (ppm * ppm * 30.0)) + 1)):
        ph, pw = int(rng.uniform(0.5, 3) * ppm) + 1, int(rng.uniform(0.5, 3) * ppm) + 1
        y0, x0 = int(rng.uniform(0, max(1, h - ph))), int(rng.uniform(0, max(1, w - pw)))
        img[y0:y0 + ph, x0:x0 + pw] *= rng.uniform(0.75, 1.2)
    for _ in range(int(rng.poisson(h * w / (ppm * ppm * 15.0)) + 1)):
        pts = np.cumsum(rng.normal(0, 0.3 * ppm, (int(rng.integers(3, 9)), 2)), axis=0) + [rng.uniform(0, w), rng.uniform(0, h)]
        cv2.polylines(img, [pts.astype(np.int32)], False, (35, 35, 38), 1, cv2.LINE_AA)


def paving(base_rgb=(165, 160, 150)) -> Painter:
    def paint(h, w, ppm, rng):
        s = max(3.0, 0.5 * ppm)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r, c = np.floor(yy / s).astype(int), np.floor(xx / s).astype(int)
        jit = rng.uniform(0.8, 1.15, (r.max() + 1, c.max() + 1)).astype(np.float32)
        img = np.asarray(colour_jitter(base_rgb, rng, 0.08), np.float32) * jit[r, c][..., None]
        img[((yy % s) < 1) | ((xx % s) < 1)] *= 0.7
        img = _modulate(img, fbm(h, w, 2.0 * ppm, rng, 5), 0.15)
        _blobs(img, rng, int(1 + h * w / (ppm * ppm * 6)), 0.4 * ppm, 0.35)
        return _to_u8(img)
    return paint


def grass(h, w, ppm, rng):
    img = np.empty((h, w, 3), np.float32)
    img[:] = colour_jitter((70, 120, 50), rng, 0.1)
    img = _modulate(img, fbm(h, w, 2.0 * ppm, rng, 6), 0.35)
    return _to_u8(img)


def foliage(h, w, ppm, rng):
    img = np.empty((h, w, 3), np.float32)
    img[:] = colour_jitter((55, 105, 40), rng, 0.2)
    img = _modulate(img, fbm(h, w, 0.8 * ppm, rng, 5, gain=0.7), 0.5)
    _blobs(img, rng, int(3 + h * w / (ppm * ppm * 0.5)), 0.15 * ppm, 0.4)
    return _to_u8(img)


def bark(h, w, ppm, rng):
    img = np.empty((h, w, 3), np.float32)
    img[:] = colour_jitter((90, 65, 45), rng, 0.1)
    streaks = cv2.resize(rng.random((max(2, h // 8), max(2, w // 2)), dtype=np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    img = _modulate(img, 0.6 * np.clip(streaks, 0, 1) + 0.4 * rng.random((h, w), dtype=np.float32), 0.35)
    return _to_u8(img)


def metal(base_rgb=(120, 125, 130)) -> Painter:
    def paint(h, w, ppm, rng):
        img = np.empty((h, w, 3), np.float32)
        img[:] = colour_jitter(base_rgb, rng, 0.15)
        img = _modulate(img, fbm(h, w, ppm, rng, 4), 0.2)
        for _ in range(int(rng.integers(0, 3))):
            y = int(rng.uniform(0, h))
            img[y:y + max(1, int(0.05 * ppm))] = rng.uniform(0, 255, 3)  # stickers / bands
        return _to_u8(img)
    return paint


def sign_face(h, w, ppm, rng):
    """A traffic/street sign: coloured plate with a border and a number or word."""
    img = np.empty((h, w, 3), np.float32)
    kind = int(rng.integers(0, 4))
    bg = [(240, 240, 240), (30, 90, 200), (240, 200, 20), (30, 140, 60)][kind]
    img[:] = bg
    b = max(1, int(0.08 * min(h, w)))
    border = (200, 30, 30) if kind == 0 else (250, 250, 250)
    img[:b] = border
    img[-b:] = border
    img[:, :b] = border
    img[:, -b:] = border
    text = str(int(rng.choice([20, 30, 40, 50, 60, 70]))) if kind == 0 else _rand_text(rng, int(rng.integers(2, 5)))
    put_text_box(img, b, b, w - b, h - b, text, (20, 20, 20) if kind in (0, 2) else (250, 250, 250), bg)
    return _to_u8(_modulate(img, value_noise(h, w, max(2.0, 0.1 * ppm), rng), 0.08))


def car_body(base_rgb) -> Painter:
    """Side/front/back of a car body: paint with reflections, door seams, a plate."""
    def paint(h, w, ppm, rng):
        img = np.empty((h, w, 3), np.float32)
        img[:] = colour_jitter(base_rgb, rng, 0.1)
        t = np.linspace(0, 1, h, dtype=np.float32)[:, None, None]
        img = img * (1.15 - 0.4 * t)
        img = _modulate(img, fbm(h, w, 0.6 * ppm, rng, 3), 0.1)
        for _ in range(int(rng.integers(1, 4))):  # seams
            x = int(rng.uniform(0.15, 0.85) * w)
            img[:, x:x + 1] *= 0.5
        img[int(0.75 * h):] *= 0.45  # dark skirt / bumper
        if w > 8 and h > 6 and rng.random() < 0.8:
            pw, ph = max(4, int(0.5 * ppm)), max(3, int(0.12 * ppm))
            x0, y0 = (w - pw) // 2, int(0.55 * h)
            put_text_box(img, x0, y0, x0 + pw, y0 + ph, _rand_text(rng, 5), (20, 20, 20), (235, 235, 235))
        return _to_u8(img)
    return paint


def car_glass(h, w, ppm, rng):
    img = np.empty((h, w, 3), np.float32)
    t = np.linspace(0, 1, h, dtype=np.float32)[:, None, None]
    img[:] = rng.uniform(90, 170, 3) * (1 - t) + rng.uniform(15, 50, 3) * t
    img = _modulate(img, value_noise(h, w, max(2, 0.3 * ppm), rng), 0.3)
    for _ in range(int(rng.integers(1, 3))):  # pillars
        x = int(rng.uniform(0, w))
        img[:, x:x + max(1, int(0.08 * ppm))] = 25
    return _to_u8(img)


def tyre_band(h, w, ppm, rng):
    img = np.full((h, w, 3), 28, np.float32)
    for frac in (0.2, 0.8):
        c = (int(frac * w), h // 2)
        r = max(1, int(0.35 * ppm))
        cv2.circle(img, c, r, (15, 15, 15), -1, cv2.LINE_AA)
        cv2.circle(img, c, max(1, r // 2), (150, 150, 155), -1, cv2.LINE_AA)
    return _to_u8(_modulate(img, value_noise(h, w, 2, rng), 0.2))


def flat(rgb, noise: float = 0.1) -> Painter:
    def paint(h, w, ppm, rng):
        img = np.empty((h, w, 3), np.float32)
        img[:] = colour_jitter(rgb, rng, 0.05)
        return _to_u8(_modulate(img, fbm(h, w, max(2.0, ppm), rng, 3), noise))
    return paint


# ----------------------------------------------------------------------------------------------
# indoor painters (room)
# ----------------------------------------------------------------------------------------------

def indoor_wall(rng_style: np.random.Generator) -> Painter:
    """A hall wall: paint or concrete, posters, calibration-like boards, cables, marks."""
    base = rng_style.uniform(120, 235, 3)
    concrete = rng_style.random() < 0.5

    def paint(h, w, ppm, rng):
        img = np.empty((h, w, 3), np.float32)
        img[:] = colour_jitter(base, rng, 0.05)
        img = _modulate(img, fbm(h, w, 0.8 * ppm, rng, 6), 0.25 if concrete else 0.1)
        if concrete:  # formwork tie holes and panel joints
            pw, ph = max(4, int(rng.uniform(1.2, 2.4) * ppm)), max(4, int(rng.uniform(0.6, 1.2) * ppm))
            img[::ph] *= 0.8
            img[:, ::pw] *= 0.8
            for y in range(ph // 2, h, ph):
                for x in range(pw // 4, w, pw // 2):
                    cv2.circle(img, (x, y), max(1, int(0.015 * ppm)), (60, 60, 60), -1, cv2.LINE_AA)
        for _ in range(int(rng.poisson(w * h / (ppm * ppm * 1.5)) + 2)):
            ph, pw = int(rng.uniform(0.3, 1.0) * ppm) + 2, int(rng.uniform(0.25, 0.8) * ppm) + 2
            x0, y0 = int(rng.uniform(0, max(1, w - pw))), int(rng.uniform(0, max(1, h - ph)))
            r = rng.random()
            if r < 0.5:
                img[y0:y0 + ph, x0:x0 + pw] = poster(ph, pw, rng)[: h - y0, : w - x0]
            elif r < 0.7:  # checkerboard / marker board
                n = int(rng.integers(4, 9))
                yy, xx = np.mgrid[0:ph, 0:pw]
                board = (((yy * n) // ph + (xx * n) // pw) % 2).astype(np.float32) * 220 + 20
                img[y0:y0 + ph, x0:x0 + pw] = board[: h - y0, : w - x0, None]
            else:  # random dots board (AprilTag-like blocks)
                g = int(rng.integers(4, 8))
                cells = (rng.random((g, g)) < 0.5).astype(np.float32) * 230 + 15
                blk = cv2.resize(cells, (pw, ph), interpolation=cv2.INTER_NEAREST)
                img[y0:y0 + ph, x0:x0 + pw] = blk[: h - y0, : w - x0, None]
        for _ in range(int(rng.integers(1, 5))):  # cables / pipes
            y = int(rng.uniform(0, h))
            pts = np.array([[0, y]] + [[x, y + rng.normal(0, 0.05 * ppm)] for x in np.linspace(0, w, 12)[1:]])
            cv2.polylines(img, [pts.astype(np.int32)], False, tuple(float(c) for c in rng.uniform(0, 200, 3)),
                          max(1, int(0.03 * ppm)), cv2.LINE_AA)
        _blobs(img, rng, int(rng.poisson(w * h / (ppm * ppm * 2.0)) + 1), 0.3 * ppm, 0.3)
        return _to_u8(img)
    return paint


def floor_mat(h, w, ppm, rng):
    """Hall floor: tiles or boards with tape marks, scuffs and stains."""
    img = np.empty((h, w, 3), np.float32)
    img[:] = colour_jitter(rng.uniform(90, 200, 3), rng, 0.05)
    s = max(3, int(rng.uniform(0.4, 1.0) * ppm))
    yy, xx = np.mgrid[0:h, 0:w]
    r, c = yy // s, xx // s
    jit = rng.uniform(0.85, 1.12, (r.max() + 1, c.max() + 1)).astype(np.float32)
    img = img * jit[r, c][..., None]
    img[(yy % s == 0) | (xx % s == 0)] *= 0.7
    img = _modulate(img, fbm(h, w, 0.8 * ppm, rng, 6), 0.2)
    for _ in range(int(rng.poisson(w * h / (ppm * ppm * 3.0)) + 2)):  # tape marks
        p0 = rng.uniform(0, 1, 2) * [w, h]
        p1 = p0 + rng.normal(0, 1.0 * ppm, 2)
        cv2.line(img, tuple(int(v) for v in p0), tuple(int(v) for v in p1),
                 tuple(float(c) for c in rng.choice([(230, 200, 20), (240, 240, 240), (200, 40, 40), (30, 30, 30)])),
                 max(1, int(0.05 * ppm)), cv2.LINE_AA)
    _blobs(img, rng, int(rng.poisson(w * h / (ppm * ppm)) + 2), 0.25 * ppm, 0.3)
    return _to_u8(img)


def wood(h, w, ppm, rng):
    img = np.empty((h, w, 3), np.float32)
    img[:] = colour_jitter((160, 115, 70), rng, 0.15)
    grain = cv2.resize(rng.random((max(2, h // 2), max(2, w // 20)), dtype=np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    img = _modulate(img, np.clip(0.7 * grain + 0.3 * rng.random((h, w), dtype=np.float32), 0, 1), 0.25)
    return _to_u8(img)


def cardboard(h, w, ppm, rng):
    """A labelled box side: cardboard with printed text, arrows and barcodes."""
    img = np.empty((h, w, 3), np.float32)
    if rng.random() < 0.6:
        img[:] = colour_jitter((185, 145, 95), rng, 0.1)
    else:
        img[:] = rng.uniform(20, 240, 3)
    img = _modulate(img, fbm(h, w, max(2.0, 0.2 * ppm), rng, 4), 0.15)
    if h >= 8 and w >= 8:
        put_text_box(img, int(0.1 * w), int(0.1 * h), int(0.9 * w), int(0.4 * h), _rand_text(rng, int(rng.integers(2, 6))),
                     rng.uniform(0, 120, 3), img[int(0.25 * h), int(0.5 * w)].copy())
        bars = (rng.random(max(2, w // 3)) < 0.5).astype(np.float32)
        bar_img = cv2.resize(bars[None, :], (int(0.6 * w), max(1, int(0.2 * h))), interpolation=cv2.INTER_NEAREST)
        y0, x0 = int(0.6 * h), int(0.2 * w)
        region = img[y0:y0 + bar_img.shape[0], x0:x0 + bar_img.shape[1]]
        region[bar_img[: region.shape[0], : region.shape[1]] > 0.5] = 20
    return _to_u8(img)
