"""Where in the image a flow -> 6DoF network takes its reading from, and whether it reads a scene's mirror image
alike.

A network trained on rendered towns may learn the towns' layout along with the geometry: which part of the
image usually shows the open road, and so how much flow a metre of travel makes there. Two probes tell:

- :func:`integrated_gradients` (Sundararajan et al., 2017) splits one output of the network (a DoF of the pose
  mean) over the input pixels, from a baseline of zero flow: the attributions plus the output at zero flow sum to
  the output (to the path integral's discretisation error), so a region's share says how much of the reading
  comes from there. :func:`region_sums` adds them up over a coarse grid.
- :func:`mirror_input` flips the network's input left-right (a scene seen in a mirror, moving as the mirror image
  of the motion): a network that reads geometry reads the mirrored flow's forward motion as the original's; one
  that learned where the open road lies in its training images does not.

Arrays are the network's input: flow ``(B, 2, h, w)`` float32 px at network resolution (u right, v down, OpenCV
axes), intrinsics ``(B, 4)`` float32 ``(fx, fy, cx, cy)`` at that resolution.
"""
from __future__ import annotations

import numpy as np
import torch


def mirror_input(flow: np.ndarray, intrinsics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The network input of the scene flipped left-right: columns reversed, the flow's u negated, the principal
    point's column mirrored (``w - 1 - cx``, :meth:`core.camera.PinholeCamera.mirrored`).

    Args:
        flow: (B, 2, h, w) float32 px.
        intrinsics: (B, 4) float32 ``(fx, fy, cx, cy)`` px at the flow's resolution.

    Returns:
        (flow, intrinsics) of the same shapes and dtype; mirroring twice gives the input back.
    """
    flow = np.asarray(flow)
    out = np.ascontiguousarray(flow[..., ::-1])
    out[:, 0] = -out[:, 0]
    intr = np.array(intrinsics, copy=True)
    intr[:, 2] = flow.shape[-1] - 1 - intr[:, 2]
    return out, intr


def integrated_gradients(model: torch.nn.Module, flow: np.ndarray, intrinsics: np.ndarray, output: int,
                         steps: int = 32, batch: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Integrated gradients of the network's pose mean, DoF ``output``, with respect to the input flow, from a
    baseline of zero flow (midpoint rule over ``steps`` points of the straight path), in float32 on the model's
    device.

    Args:
        model: a :class:`vo.net.PoseNet` without a depth channel (``model(flow, intrinsics, None)`` -> (mean6,
            log_std6)); put in eval mode here.
        flow: (B, 2, h, w) float32 px.
        intrinsics: (B, 4) float32 px.
        output: index of the paper vector's DoF (0-2 euler x, y, z in rad; 3-5 t x, y, z in m).
        steps: points of the path from zero flow to ``flow``.
        batch: pairs per forward pass.

    Returns:
        ``(attribution, at_zero)``: float64 (B, h, w), each pixel's share of the output (the unit of the DoF;
        summed over the two flow channels), and float64 (B,) the output at zero flow; ``attribution.sum((1, 2)) +
        at_zero`` is the output at ``flow`` up to the discretisation error.
    """
    if getattr(getattr(model, "cfg", None), "depth_channel", False):
        raise ValueError("integrated_gradients reads flow-only networks (this one takes the frame's depth too)")
    if not 0 <= int(output) < 6 or int(steps) < 1:
        raise ValueError(f"output must be in 0..5 and steps >= 1, got {output} and {steps}")
    model.eval()
    device = next(model.parameters()).device
    attributions, zeros = [], []
    for s in range(0, len(flow), batch):
        x = torch.as_tensor(np.asarray(flow[s:s + batch], dtype=np.float32), device=device)
        k = torch.as_tensor(np.asarray(intrinsics[s:s + batch], dtype=np.float32), device=device)
        grads = torch.zeros_like(x)
        for i in range(int(steps)):
            xi = (x * ((i + 0.5) / steps)).requires_grad_(True)
            mean, _ = model(xi, k, None)
            (grad,) = torch.autograd.grad(mean[:, output].sum(), xi)
            grads += grad
        with torch.no_grad():
            zeros.append(model(torch.zeros_like(x), k, None)[0][:, output].double().cpu())
        attributions.append((x * grads / steps).sum(1).double().cpu())
    if not attributions:
        return np.zeros((0,) + tuple(np.shape(flow)[2:])), np.zeros(0)
    return torch.cat(attributions).numpy(), torch.cat(zeros).numpy()


def region_sums(attribution: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Sums of (B, h, w) per-pixel values over a ``rows`` x ``cols`` grid of equal cells (rows top to bottom,
    columns left to right; the last cells take the remainder of an uneven split): float64 (B, rows, cols)."""
    a = np.asarray(attribution, dtype=np.float64)
    h, w = a.shape[1:]
    if not (1 <= rows <= h and 1 <= cols <= w):
        raise ValueError(f"a {rows} x {cols} grid does not fit a {h} x {w} image")
    r = np.linspace(0, h, rows + 1).astype(int)
    c = np.linspace(0, w, cols + 1).astype(int)
    return np.stack([np.stack([a[:, r[i]:r[i + 1], c[j]:c[j + 1]].sum((1, 2)) for j in range(cols)], -1)
                     for i in range(rows)], 1)
