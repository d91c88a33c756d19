"""Pose from flow and depth by weighted Gauss-Newton, and the network that learns its weights.

For cameras that know the first frame's depth at test time (RGB-D, renders, stereo), the motion
``cam1_from_cam0`` that moves each pixel along its flow is a small least-squares problem: a pixel
``p0 = (u, v)`` with normalised ray ``b = ((u - cx) / fx, (v - cy) / fy, 1)`` and inverse depth
``rho`` (1/m, of ``depth_z``) lands at the projection of ``Q = R b + rho t`` (the point ``b / rho``
moved into camera 1, scaled by ``rho``: the projection does not change). :func:`solve_pose` finds
``(R, t)`` minimising ``sum_p w_p |proj(Q_p) - p1_p|^2`` (pixels, per image axis) from ``R = I, t = 0``
by Gauss-Newton with left perturbations ``R <- exp(dw) R, t <- exp(dw) t + dt``. With every weight
1 and exact flow this is the exact motion (up to the resize of flow and depth to the network's
resolution); with DIS's flow on a real camera the pixels are not equally right, and
:class:`FlowSolvePoseNet` learns, from the flow, the inverse depth and where both are known, a weight
per pixel and image axis: the paper's flow -> 6DoF network with its regression head replaced by this
solve (``NetConfig.pose_head = "solve"``). Its uncertainty is the solve's own: the diagonal of
``H^-1`` (H = J^T W J, the Gauss-Newton normal matrix, in (dw, dt) coordinates) gives a log-std
feature per DoF that the stage-2 heads (one 3 x 3 linear map each for rotation and translation)
calibrate on held-out samples with the Gaussian NLL, as for the paper's network (:mod:`vo.train`).

Axes are OpenCV's (x right, y down, z forward); rotations and the output vector are the paper's
(:func:`core.se3.to_euler6`: euler x, y, z in radians with R = Rz Ry Rx, then t in metres).
"""
from __future__ import annotations

import dataclasses

import torch
from torch import nn

from deepslam.vo.net import LOG_STD_MAX, LOG_STD_MIN, NetConfig, PoseNet, register_input_buffers


LOG_WEIGHT_LIMIT = 10.0
"""The learned log-weights are clamped to [-LOG_WEIGHT_LIMIT, LOG_WEIGHT_LIMIT] (weights in 1/px^2)."""
ROBUST_KERNELS = ("none", "cauchy")
"""The values of :attr:`vo.net.NetConfig.solve_robust`."""
CAUCHY_C = 2.3849
"""Cauchy kernel's scale in units of the residuals' robust standard deviation (1.4826 x their median
absolute value): the usual constant for 95 % efficiency on Gaussian residuals (not tuned here)."""
MIN_ROBUST_SCALE_PX = 1e-3
"""Floor of the Cauchy kernel's scale, pixels (exact flow leaves residuals of ~0 at the solution)."""
DAMPING = 1e-6
"""Levenberg damping of the Gauss-Newton step, relative to the mean of diag(H) (plus 1e-12 absolute,
so that a field with no usable pixel answers the identity instead of failing)."""


def _skew(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrices [v]x."""
    z = torch.zeros_like(v[..., 0])
    return torch.stack([torch.stack([z, -v[..., 2], v[..., 1]], -1),
                        torch.stack([v[..., 2], z, -v[..., 0]], -1),
                        torch.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def so3_exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3) in radians (Rodrigues; series near 0)."""
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]
    theta = theta2.clamp_min(1e-30).sqrt()
    small = theta2 < 1e-8
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp_min(1e-30))
    k = _skew(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(k)
    return eye + a * k + b * (k @ k)


def euler6(rot: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """The paper's vector (B, 6) of rotations (B, 3, 3) and translations (B, 3): euler x, y, z (radians,
    R = Rz Ry Rx, as :func:`core.se3.to_euler6`), then t (metres)."""
    ex = torch.atan2(rot[:, 2, 1], rot[:, 2, 2])
    ey = torch.atan2(-rot[:, 2, 0], torch.sqrt(rot[:, 2, 1] ** 2 + rot[:, 2, 2] ** 2))
    ez = torch.atan2(rot[:, 1, 0], rot[:, 0, 0])
    return torch.cat([torch.stack([ex, ey, ez], 1), t], 1)


def solve_pose(flow_px: torch.Tensor, inv_depth: torch.Tensor, intrinsics: torch.Tensor, weights: torch.Tensor,
               iterations: int = 3, robust: str = "none") -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Weighted Gauss-Newton for ``cam1_from_cam0`` from a flow field and the first frame's depth.

    Args:
        flow_px: (B, 2, h, w) float flow (du, dv) in pixels from frame 0 to frame 1; NaN where unknown.
        inv_depth: (B, 1, h, w) float 1 / depth_z of frame 0 in 1/m; <= 0 or non-finite where unknown.
        intrinsics: (B, 4) float fx, fy, cx, cy in pixels at the flow's resolution.
        weights: (B, 2, h, w) float >= 0 weight of each pixel's u and v residual (1/px^2); pixels
            with unknown flow or depth get 0 here whatever is given.
        iterations: Gauss-Newton steps from the identity (the first is the linear motion-field solve);
            under autograd only the last step is differentiated (the implicit gradient at convergence).
        robust: ``none`` (least squares) or ``cauchy``: from the second step on, iteratively reweighted
            least squares: each residual's weight is multiplied by ``1 / (1 + (r / c)^2)``, r the residual
            (px) at the current estimate and c = :data:`CAUCHY_C` x 1.4826 x the median |r| over the
            sample's weighted pixels (both image axes); these factors are not differentiated. Pixels the
            flow gets wrong (occlusion, moving objects, DIS's failures on a real camera) then stop
            pulling the pose; with exact flow the solution is the same.

    Returns:
        (rotation (B, 3, 3), translation (B, 3) metres, H (B, 6, 6) the normal matrix J^T W J of the
        last step (at the solution to first order) in (dw radians, dt metres) coordinates and the
        weights' 1/px^2), float64 (the per-pixel terms are float32, the normal equations are summed
        and solved in float64).
    """
    if robust not in ROBUST_KERNELS:
        raise ValueError(f"robust must be one of {', '.join(ROBUST_KERNELS)}, got {robust!r}")
    b, _, h, w = flow_px.shape
    f32 = dict(dtype=torch.float32, device=flow_px.device)
    f64 = dict(dtype=torch.float64, device=flow_px.device)
    flow = flow_px.float()
    rho = inv_depth.float()
    known = torch.isfinite(flow).all(1, keepdim=True) & torch.isfinite(rho) & (rho > 0)
    wts = torch.where(known, weights.float(), 0.0).reshape(b, 2, -1)                       # (B, 2, N)
    flow = torch.where(known, flow, 0.0).reshape(b, 2, -1)
    rho = torch.where(known, rho, 0.0).reshape(b, -1)                                     # (B, N)
    k = intrinsics.float()
    fx, fy, cx, cy = (k[:, i:i + 1] for i in range(4))                                    # (B, 1)
    v, u = torch.meshgrid(torch.arange(h, **f32), torch.arange(w, **f32), indexing="ij")
    u, v = u.reshape(1, -1), v.reshape(1, -1)
    ray = torch.stack([(u - cx) / fx, (v - cy) / fy, torch.ones_like(u - cx)], 1)        # (B, 3, N)
    tx, ty = (u + flow[:, 0] - cx) / fx, (v + flow[:, 1] - cy) / fy                        # (B, N)
    rot = torch.eye(3, **f64).expand(b, 3, 3)
    t = torch.zeros(b, 3, **f64)
    eye6 = torch.eye(6, **f64)
    for it in range(iterations):
        # the steps before the last run without autograd: at convergence the last step's gradient is
        # the implicit one (d pose / d w = -H^-1 d grad / d w), at a fraction of the memory and time
        with torch.set_grad_enabled(torch.is_grad_enabled() and it == iterations - 1):
            q = rot.float() @ ray + rho[:, None, :] * t.float()[..., None]                   # (B, 3, N)
            front = q[:, 2] > 1e-6
            iz = torch.where(front, 1.0 / torch.where(front, q[:, 2], 1.0), 0.0)
            px, py = q[:, 0] * iz, q[:, 1] * iz
            wu, wv = wts[:, 0] * front, wts[:, 1] * front
            ru, rv = (px - tx) * fx, (py - ty) * fy                                              # (B, N) px
            if robust == "cauchy" and it > 0:
                ku, kv = cauchy_factors(ru.detach(), rv.detach(), wu > 0, wv > 0)
                wu, wv = wu * ku, wv * kv
            # d proj / d (dw, dt) of R <- exp(dw) R, t <- exp(dw) t + dt: the interaction matrix, in pixels
            zero = torch.zeros_like(px)
            ju = torch.stack([-px * py, 1.0 + px * px, -py, rho * iz, zero, -rho * px * iz], 1) * fx[..., None]
            jv = torch.stack([-1.0 - py * py, px * py, px, zero, rho * iz, -rho * py * iz], 1) * fy[..., None]
            hess = ((ju * wu[:, None]) @ ju.transpose(1, 2) + (jv * wv[:, None]) @ jv.transpose(1, 2)).double()
            grad = (ju @ (wu * ru)[..., None] + jv @ (wv * rv)[..., None])[..., 0].double()       # (B, 6)
            lam = DAMPING * hess.diagonal(dim1=1, dim2=2).mean(-1) + 1e-12
            step = -torch.linalg.solve(hess + lam[:, None, None] * eye6, grad)
            dr = so3_exp(step[:, :3])
            rot = dr @ rot
            t = (dr @ t[..., None])[..., 0] + step[:, 3:]
    return rot, t, hess


def cauchy_factors(ru: torch.Tensor, rv: torch.Tensor, use_u: torch.Tensor, use_v: torch.Tensor
                   ) -> tuple[torch.Tensor, torch.Tensor]:
    """Cauchy reweighting factors (B, N) float32 in (0, 1] of the u and v residuals ``ru``, ``rv`` (B, N)
    px; the kernel's scale per sample from the median |r| over the residuals marked in ``use_u`` /
    ``use_v`` (B, N) bool (a sample with none marked gets factors 1)."""
    r = torch.cat([ru, rv], 1)
    used = torch.cat([use_u, use_v], 1)
    med = torch.nanmedian(torch.where(used, r.abs(), torch.nan), dim=1).values                # (B,)
    med = torch.nan_to_num(med, nan=1.0)
    c = (CAUCHY_C * 1.4826 * med).clamp_min(MIN_ROBUST_SCALE_PX)[:, None]
    return 1.0 / (1.0 + (ru / c) ** 2), 1.0 / (1.0 + (rv / c) ** 2)


class FlowSolvePoseNet(PoseNet):
    """Flow (B, 2, h, w) px + intrinsics (B, 4) + inverse depth (B, 1, h, w) -> 6DoF mean and log-std,
    through :func:`solve_pose` with learned per-pixel weights (see the module docstring).

    The weight network (``cfg.filters`` channels, 3 x 3 kernels): a convolution of stride 2 (half
    resolution), one more of stride 2 and a dilated one at a quarter resolution, upsampled and joined
    with the first's features, a last convolution to two log-weights per half-resolution pixel
    (started at 0: every weight 1, the plain least-squares solve), upsampled bilinearly to the input's
    pixels. ``cfg.kernels``, ``strides``, ``hidden_units`` and ``hidden_layers`` are not used. The
    interface is :class:`vo.net.FlowPoseNet`'s: ``trunk`` returns (mean (B, 6), the
    solve's log-std feature 0.5 log diag(H^-1) (B, 6)), ``mean_head`` the first, ``log_std_head`` maps
    the second through the stage-2 heads ``rot_log_std`` and ``trans_log_std`` (Linear 3 -> 3).
    """

    def __init__(self, cfg: NetConfig):
        super().__init__()
        if cfg.pose_head != "solve":
            raise ValueError(f"FlowSolvePoseNet needs pose_head='solve', got {cfg.pose_head!r}")
        self.cfg = cfg
        f = cfg.filters
        self.enc1 = nn.Sequential(nn.Conv2d(cfg.in_channels, f, 3, stride=2, padding=1), nn.ReLU(inplace=True))
        self.enc2 = nn.Sequential(nn.Conv2d(f, f, 3, stride=2, padding=1), nn.ReLU(inplace=True),
                                  nn.Conv2d(f, f, 3, padding=2, dilation=2), nn.ReLU(inplace=True))
        self.weight_out = nn.Conv2d(2 * f, 2, 3, padding=1)
        nn.init.zeros_(self.weight_out.weight)
        nn.init.zeros_(self.weight_out.bias)
        self.rot_log_std = nn.Linear(3, 3)
        self.trans_log_std = nn.Linear(3, 3)
        for head in (self.rot_log_std, self.trans_log_std):
            nn.init.eye_(head.weight)
            nn.init.zeros_(head.bias)
        register_input_buffers(self, cfg)

    def log_weights(self, flow_px, intrinsics, inv_depth) -> torch.Tensor:
        """(B, 2, h, w) float32 learned log-weights (1/px^2) of each pixel's u and v residual."""
        x = self.prepare_input(flow_px, intrinsics, inv_depth)
        c1 = self.enc1(x)
        c2 = nn.functional.interpolate(self.enc2(c1), size=c1.shape[-2:], mode="bilinear", align_corners=False)
        out = self.weight_out(torch.cat([c1, c2], 1)).float()
        out = nn.functional.interpolate(out, size=x.shape[-2:], mode="bilinear", align_corners=False)
        return out.clamp(-LOG_WEIGHT_LIMIT, LOG_WEIGHT_LIMIT)

    def trunk(self, flow_px, intrinsics=None, inv_depth=None) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean (B, 6) float32 paper vector of cam1_from_cam0, 0.5 log diag(H^-1) (B, 6) float32)."""
        if intrinsics is None or inv_depth is None:
            raise ValueError("a solve-head network needs the intrinsics and the first frame's inverse depth")
        log_w = self.log_weights(flow_px, intrinsics, inv_depth)
        with torch.autocast(flow_px.device.type, enabled=False):
            rot, t, hess = solve_pose(flow_px, inv_depth, intrinsics, torch.exp(log_w), self.cfg.solve_iterations,
                                        self.cfg.solve_robust)
            eye = torch.eye(6, dtype=hess.dtype, device=hess.device)
            cov_diag = torch.linalg.solve(hess + 1e-12 * eye, eye.expand_as(hess)).diagonal(dim1=1, dim2=2)
            feat = 0.5 * torch.log(cov_diag.clamp(1e-24, 1e24))
            return euler6(rot, t).float(), feat.float()

    @torch.no_grad()
    def calibrate_log_std(self, ht: torch.Tensor, rmse: torch.Tensor) -> None:
        """Start stage 2: heads = identity plus a bias that makes the mean log-std over the held-out
        features ``ht`` (N, 6) equal log(``rmse``) (6,) per DoF."""
        for k, head in enumerate((self.rot_log_std, self.trans_log_std)):
            part = slice(3 * k, 3 * k + 3)
            head.weight.copy_(torch.eye(3))
            head.bias.copy_(rmse[part].log() - ht[:, part].mean(0))

    def mean_head(self, hr: torch.Tensor, ht: torch.Tensor) -> torch.Tensor:
        """The solved pose (``hr``, (B, 6))."""
        return hr

    def log_std_head(self, hr: torch.Tensor, ht: torch.Tensor) -> torch.Tensor:
        """(B, 6) log-std: the stage-2 heads applied to the solve's log-std feature ``ht``, clamped."""
        with torch.autocast(ht.device.type, enabled=False):
            log_std = torch.cat([self.rot_log_std(ht[:, :3]), self.trans_log_std(ht[:, 3:])], dim=1)
        return log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)


def unit_weight_net(cfg: NetConfig, robust: str = "none", iterations: int | None = None) -> FlowSolvePoseNet:
    """The solve pose head, untrained, at ``cfg``'s input size and flow scaling: every weight 1, so its
    pose is the plain least-squares fit of the flow with the frame's depth (a classical dense
    flow + depth odometry that runs through the learned models' path); ``robust="cauchy"`` makes it the
    iteratively reweighted fit (:func:`solve_pose`), with ``iterations`` Gauss-Newton steps (default:
    ``cfg``'s)."""
    return FlowSolvePoseNet(dataclasses.replace(
        cfg, depth_channel=True, valid_channel=True, pose_head="solve", solve_robust=robust,
        solve_iterations=cfg.solve_iterations if iterations is None else iterations))
