"""Unsupervised fine-tuning of the learned flow on real frame pairs without flow labels.

The flow network trained on renders alone has its own sim-to-real gap (on real KITTI it is less
forward-backward consistent than DIS, ``bench.results_flow``). Real video gives what it needs without
labels: the second image itself. The loss used here is the one the unsupervised-flow literature settled
on (UFlow, Jonschkowski et al. 2020; ARFlow, Liu et al. 2020), written for this network:

- **census photometric loss**: each pixel is described by the soft signs of its 7x7 neighbourhood's
  differences from it (robust to the exposure and gain changes between real frames); the loss is the
  soft Hamming distance between the first image's descriptor and that of the second image sampled at
  pixel + flow, through the robust ``(|x| + 0.01) ** 0.4``;
- **occlusion mask** from the forward-backward check (Brox's test, ``|f + b(x + f)|^2 < 0.01 (|f|^2 +
  |b(x + f)|^2) + 0.5``, gradient stopped): occluded pixels have no match and are left out, as are
  pixels flowing out of the crop and the census's border (an untrained network fails the check almost
  everywhere; then only the in-image mask is used, :data:`MIN_CONSISTENT_SHARE`);
- **edge-aware smoothness** of the flow (first or second order, at the estimate's 1/4 resolution,
  weighted by ``exp(-150 |grad I|)``), which fills what the photometric term cannot see (textureless
  road, sky). First order pulls a road plane's flow, which grows towards the image bottom, towards a
  constant; second order leaves a linear change free.

Both directions of each real pair are estimated and both are scored. The images the loss compares are
the un-augmented ones; the network sees photometrically augmented copies (the same draw as the
supervised pairs), so it learns to match through exposure and noise changes.

Shapes: images (B, 1, H, W) float32 in [0, 1]; flows (B, 2, H, W) px of that resolution, the
project's convention (channel 0 = du along image x, 1 = dv along image y), from the first image to the
second.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from tqdm import tqdm

from deepslam.core.errors import InputError
from deepslam.flow.augment import crop_pair, photometric_pair
from deepslam.flow.images import to_grey
from deepslam.flow.net import resize_to_width, upsample_flow, warp

CENSUS_PATCH = 7
"""Census neighbourhood side, pixels (UFlow's)."""
SMOOTH_EDGE_WEIGHT = 150.0
"""Edge-awareness of the smoothness term: weight exp(-this * |grad I|), I in [0, 1]."""
MIN_CONSISTENT_SHARE = 0.25
"""Below this share of forward-backward consistent pixels in a batch the check says more about the
network than about occlusions (an untrained network's flow is inconsistent nearly everywhere, and
masking it all would leave nothing to learn from), so only the in-image mask is used for that batch."""


def census_descriptor(img: torch.Tensor, patch: int = CENSUS_PATCH) -> torch.Tensor:
    """(B, patch^2, H, W): the soft census transform of grey ``img`` (B, 1, H, W) in [0, 1]: each
    neighbour's difference from the centre in grey levels d, as d / sqrt(0.81 + d^2) (a soft sign)."""
    k = patch * patch
    eye = torch.eye(k, dtype=img.dtype, device=img.device).view(k, 1, patch, patch)
    x = img * 255.0
    d = F.conv2d(x, eye, padding=patch // 2) - x
    return d / torch.sqrt(0.81 + d * d)


def census_distance(t0: torch.Tensor, t1: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W): soft Hamming distance between two census descriptors (0 = identical)."""
    sq = (t0 - t1) ** 2
    return (sq / (0.1 + sq)).sum(1, keepdim=True)


def _border_mask(b: int, h: int, w: int, margin: int, like: torch.Tensor) -> torch.Tensor:
    m = torch.zeros(b, 1, h, w, dtype=like.dtype, device=like.device)
    m[:, :, margin:h - margin, margin:w - margin] = 1.0
    return m


def non_occluded(fw: torch.Tensor, bw: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) float {0, 1}: 1 where the forward flow ``fw`` lands inside the image and the
    backward flow ``bw`` there brings it back (Brox's forward-backward test; when fewer than
    :data:`MIN_CONSISTENT_SHARE` of the landing-inside pixels pass, all of them are kept); no gradient."""
    with torch.no_grad():
        bw_at = warp(bw, fw)
        s = ((fw + bw_at) ** 2).sum(1, keepdim=True)
        ok = s < 0.01 * ((fw ** 2).sum(1, keepdim=True) + (bw_at ** 2).sum(1, keepdim=True)) + 0.5
        _, _, h, w = fw.shape
        gy, gx = torch.meshgrid(torch.arange(h, dtype=fw.dtype, device=fw.device),
                                torch.arange(w, dtype=fw.dtype, device=fw.device), indexing="ij")
        u, v = gx + fw[:, 0:1], gy + fw[:, 1:2]
        inside = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
        kept = ok & inside
        if kept.sum() < MIN_CONSISTENT_SHARE * inside.sum():
            kept = inside
    return kept.to(fw.dtype)


def photometric_census_loss(img0: torch.Tensor, img1: torch.Tensor, flow: torch.Tensor,
                            mask: torch.Tensor) -> torch.Tensor:
    """Mean robust census distance between ``img0`` and ``img1`` sampled at pixel + ``flow`` over
    ``mask`` (B, 1, H, W), the census border left out. A scalar."""
    b, _, h, w = img0.shape
    with torch.no_grad():
        t0 = census_descriptor(img0)
    t1 = census_descriptor(warp(img1, flow))  # warp one channel, then describe (not 49 channels warped)
    dist = census_distance(t0, t1)
    m = mask * _border_mask(b, h, w, CENSUS_PATCH // 2, img0)
    return ((dist.abs() + 0.01) ** 0.4 * m).sum() / m.sum().clamp_min(1.0)


def smoothness_loss(flow: torch.Tensor, img: torch.Tensor, order: int = 1) -> torch.Tensor:
    """Edge-aware smoothness of ``flow`` (B, 2, h, w) px at its own resolution, with edges of ``img``
    (B, 1, H, W) averaged down to it. ``order`` 1: mean absolute first difference (a constant flow is
    free); 2: mean absolute second difference (a flow varying linearly across the image, as a road
    plane's does, is free), each weighted by exp(-:data:`SMOOTH_EDGE_WEIGHT` |grad I|) summed over the
    differences it spans. A scalar, px per pixel (per pixel squared)."""
    if order not in (1, 2):
        raise ValueError(f"smoothness order must be 1 or 2, got {order}")
    im = F.adaptive_avg_pool2d(img, flow.shape[-2:])
    ex = (im[..., :, 1:] - im[..., :, :-1]).abs()
    ey = (im[..., 1:, :] - im[..., :-1, :]).abs()
    gx = flow[..., :, 1:] - flow[..., :, :-1]
    gy = flow[..., 1:, :] - flow[..., :-1, :]
    if order == 2:
        ex, ey = ex[..., :, 1:] + ex[..., :, :-1], ey[..., 1:, :] + ey[..., :-1, :]
        gx, gy = gx[..., :, 1:] - gx[..., :, :-1], gy[..., 1:, :] - gy[..., :-1, :]
    return ((torch.exp(-SMOOTH_EDGE_WEIGHT * ex) * gx.abs()).mean()
            + (torch.exp(-SMOOTH_EDGE_WEIGHT * ey) * gy.abs()).mean())


def unsupervised_loss(model, img0: torch.Tensor, img1: torch.Tensor, aug0: torch.Tensor, aug1: torch.Tensor,
                      smooth_weight: float, autocast_device: str = "cpu", smooth_order: int = 1,
                      bf16: bool = True) -> tuple[torch.Tensor, dict]:
    """The census + smoothness loss of ``model`` on real pairs (both directions), and its parts.

    Args:
        model: a :class:`flow.net.FlowNet`.
        img0, img1: (B, 1, H, W) float32 in [0, 1], the images the loss compares (H, W multiples of 32).
        aug0, aug1: the same pairs photometrically augmented: what the network is given.
        smooth_weight: weight of the smoothness term.
        smooth_order: 1 or 2, the smoothness term's order (:func:`smoothness_loss`).
        autocast_device: device type for bf16 autocast of the network's forward pass.
        bf16: whether that autocast is on.
    Returns:
        (loss scalar, {"census", "smooth", "non_occluded"} floats for the log).
    """
    b = img0.shape[0]
    with torch.autocast(autocast_device, dtype=torch.bfloat16, enabled=bf16):
        outs = model(torch.cat([aug0, aug1]), torch.cat([aug1, aug0]))

    coarse = outs[-1].float()  # (2B, 2, H/4, W/4) at the finest estimated level
    full = upsample_flow(coarse, img0.shape[-1] // coarse.shape[-1])
    fw, bw = full[:b], full[b:]
    m_fw, m_bw = non_occluded(fw, bw), non_occluded(bw, fw)
    census = 0.5 * (photometric_census_loss(img0, img1, fw, m_fw) + photometric_census_loss(img1, img0, bw, m_bw))
    smooth = 0.5 * (smoothness_loss(coarse[:b], img0, smooth_order) + smoothness_loss(coarse[b:], img1, smooth_order))
    loss = census + smooth_weight * smooth
    return loss, {"census": float(census.detach()), "smooth": float(smooth.detach()),
                  "non_occluded": float(0.5 * (m_fw.mean() + m_bw.mean()))}


class RealPairs:
    """Consecutive frame pairs of real sequences without flow labels, in memory as grey uint8 images
    resized to the network's working width (what :class:`flow.net.LearnedFlow` gives it at run time).

    Each stereo sequence gives its left and its right camera's pairs. ``batch`` crops both images of a
    pair at the same place; the loss scores both directions, so only i -> i+1 is stored.

    Args:
        sequences: opened sequences (:func:`core.readers.open_sequence`), real or rendered.
        work_width: the flow network's working width (px).
        progress: show a progress bar while loading.
    """

    def __init__(self, sequences, work_width: int, progress: bool = True):
        def resized(img):
            return resize_to_width(to_grey(img), work_width)

        self.grey0, self.grey1, self.names = [], [], []
        for seq in sequences:
            cams = [("left", seq.image)] + ([("right", seq.image_right)] if seq.has_stereo else [])
            for cam, read in cams:
                greys = [resized(read(i)) for i in tqdm(range(len(seq)), desc=f"real {seq.name} {cam}", leave=False,
                                                        disable=not progress)]
                for i in range(len(seq) - 1):
                    self.grey0.append(greys[i])
                    self.grey1.append(greys[i + 1])
                    self.names.append(f"{seq.name}:{cam}:{i}>{i + 1}")
        if not self.grey0:
            raise InputError(None, "no real frame pairs to fine-tune on (sequences of one frame?)")

    def __len__(self) -> int:
        return len(self.grey0)

    def min_size(self) -> tuple[int, int]:
        """(height, width) of the smallest resized frame, pixels."""
        return min(g.shape[0] for g in self.grey0), min(g.shape[1] for g in self.grey0)

    def batch(self, rng: np.random.Generator, n: int, crop: tuple[int, int]) -> dict[str, torch.Tensor]:
        """``n`` crops: img0, img1 (n, 1, h, w) float32 in [0, 1] as recorded, and aug0, aug1 the same
        photometrically augmented (:func:`flow.net.photometric_pair`); a random half mirrored."""
        out = {k: [] for k in ("img0", "img1", "aug0", "aug1")}
        for k in rng.integers(0, len(self), n):
            a, b, _ = crop_pair(rng, self.grey0[k], self.grey1[k], crop, "real frames (at the network's width)")
            if rng.random() < 0.5:
                a, b = a[:, ::-1], b[:, ::-1]
            a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
            aa, ab = photometric_pair(a, b, rng)
            for key, v in zip(("img0", "img1", "aug0", "aug1"), (a, b, aa, ab)):
                out[key].append(v)
        return {k: torch.from_numpy(np.stack(v)[:, None]) for k, v in out.items()}
