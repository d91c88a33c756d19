"""False colours (core/colorize.py) and the contact sheet (core/preview.py)."""
from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from deepslam.core.colorize import depth_to_rgb, flow_to_rgb, instance_colours, mask_to_rgb
from deepslam.core.errors import InputError
from deepslam.core.preview import ContactSheetConfig, contact_sheet, sheet_frames, write_contact_sheet
from deepslam.core.readers import open_sequence


def test_flow_colours_follow_the_middlebury_wheel():
    flow = np.zeros((3, 4, 2), np.float32)
    flow[0, 0] = (0, 0)                      # no motion: white
    flow[0, 1] = (5, 0)                      # right: red
    flow[0, 2] = (0, 5)                      # down: yellow
    flow[0, 3] = (-5, 0)                     # left: cyan
    flow[1, 0] = (np.nan, 1)                 # unknown: black
    flow[1, 1] = (50, 0)                     # beyond max_px: same hue, darker
    rgb = flow_to_rgb(flow, max_px=5.0)
    assert rgb.shape == (3, 4, 3) and rgb.dtype == np.uint8
    assert tuple(rgb[0, 0]) == (255, 255, 255)
    assert tuple(rgb[0, 1]) == (255, 0, 0)
    r, g, b = (int(x) for x in rgb[0, 2])
    assert r == 255 and g > 200 and b == 0
    r, g, b = (int(x) for x in rgb[0, 3])
    assert r == 0 and g > 150 and b == 255
    assert tuple(rgb[1, 0]) == (0, 0, 0)
    assert rgb[1, 1, 0] < 255 and rgb[1, 1, 1] == rgb[1, 1, 2] == 0
    # half the length: half-saturated, same hue
    half = flow_to_rgb(np.array([[[2.5, 0.0]]]), max_px=5.0)[0, 0]
    assert half[0] == 255 and 120 < half[1] == half[2] < 135
    with pytest.raises(ValueError):
        flow_to_rgb(np.zeros((3, 4)))


def test_depth_is_bright_near_and_black_where_unknown():
    depth = np.array([[1.0, 2.0, 5.0, 0.0, np.nan]], np.float32)
    rgb = depth_to_rgb(depth, near_m=1.0, far_m=5.0).astype(int)
    brightness = rgb.sum(axis=2)[0]
    assert brightness[0] > brightness[1] > brightness[2]
    assert brightness[3] == brightness[4] == 0


def test_mask_colours_are_per_id_over_the_dimmed_image():
    mask = np.array([[0, 1, 2, 1]], np.uint16)
    image = np.full((1, 4, 3), 200, np.uint8)
    rgb = mask_to_rgb(mask, image, dim=0.5)
    assert tuple(rgb[0, 0]) == (100, 100, 100)
    assert tuple(rgb[0, 1]) == tuple(rgb[0, 3]) != tuple(rgb[0, 2])
    assert tuple(instance_colours([0])[0]) == (0, 0, 0)
    assert (instance_colours(np.arange(1, 20)).astype(int).sum(axis=1) > 0).all()


def test_contact_sheet_of_a_moving_camera(plane_sequence):
    seq = open_sequence(plane_sequence)
    frames = sheet_frames(seq, 6)
    assert frames[0] == 0 and frames[-1] == len(seq) - 2 and len(frames) == 6  # the last frame has no flow
    sheet = contact_sheet(seq, ContactSheetConfig(rows=6, panel_width_px=128))
    h = round(seq.camera.height * 128 / seq.camera.width)
    assert sheet.dtype == np.uint8 and sheet.shape == (18 + 6 * h, 3 * 128, 3)  # RGB | depth | flow (no mask)
    flow_panel = sheet[18:18 + h, 256:384].astype(int)
    assert flow_panel.std() > 5, "the camera moves: the flow panel shows structure"
    depth_panel = sheet[18:18 + h, 128:256].astype(int)
    # the ground plane is nearer at the bottom of the image: brighter there (near bright)
    assert depth_panel[-5:].sum() > depth_panel[h // 2: h // 2 + 5].sum()


def test_write_contact_sheet_atomically_and_never_into_the_sequence(plane_sequence, tmp_path):
    out = write_contact_sheet(plane_sequence, tmp_path / "sheet.png", ContactSheetConfig(rows=2))
    img = cv2.imread(str(out))
    assert img is not None and img.shape[0] > 18
    assert [p.name for p in tmp_path.iterdir()] == ["sheet.png"]  # no temporary left behind
    before = sorted(os.listdir(plane_sequence))
    with pytest.raises(InputError, match="into"):
        write_contact_sheet(plane_sequence, plane_sequence / "sheet.png")
    with pytest.raises(InputError, match=r"\.png"):
        write_contact_sheet(plane_sequence, tmp_path / "sheet.jpg")
    with pytest.raises(InputError, match="at least one row"):
        write_contact_sheet(plane_sequence, tmp_path / "s2.png", ContactSheetConfig(rows=0))
    assert sorted(os.listdir(plane_sequence)) == before
