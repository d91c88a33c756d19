"""Optical flow synthesized from one depth map and a camera motion (the paper's four steps), batched in torch.

For every pixel (u, v) of frame 0 with depth ``depth_z`` the point ``p_cam0 = depth_z K^-1 (u, v, 1)`` is
moved by ``cam1_from_cam0`` and projected into frame 1; the flow is where it lands minus (u, v):
``flow[b, v, u] = (u1 - u, v1 - v)`` in pixels (OpenCV axes, pixel centres at integers).

How it is computed (fast path, exact algebra, float32): with inverse depth ``w = 1 / depth_z``,
``depth_z1 / depth_z * (u1, v1, 1) = K R K^-1 (u, v, 1) + w K t``, so the three homogeneous coordinates
(nu, nv, d) are affine in (u, v, 1, w) with 12 coefficients per sample ``M = [K R K^-1 | K t]``
computed once in float64. The two image rows of M are re-centred and scaled so that
``nu / d = 2 (u1 - cx_img) / W`` (and v), which turns "in front of the camera and inside the image"
into the single homogeneous test ``max(|nu|, |nv|) < d`` (no division; ``d`` is clamped to at most
``2^100 w``, which is <= 0 where the depth is not a positive finite number, and NaN fails every
comparison). The flow is then
``(W / 2) nu (1 / d) + cx_img - u`` with d zeroed where not valid, so those pixels come out inf/NaN
and one ``nan_to_num`` sets them to 0. Every step is an element-wise torch op (no index arithmetic, no
gather) run over chunks of a quarter million pixels so that the temporaries stay in cache, with
reused scratch buffers; degenerate input never needs a branch and never raises.

Validity (``valid``): false where the depth is not a positive finite number (0, negative, NaN, inf), where
the moved point is not in front of camera 1 (depth_z1 <= 0), where it lands outside the image area
(u1 outside (-0.5, W - 0.5) or v1 outside (-0.5, H - 0.5)), and, with ``zbuffer=True``, where it is
hidden in frame 1 by a nearer moved point of the same depth map (see :func:`synthesize`). ``flow`` is 0
wherever ``valid`` is false (never NaN).

Two implementations of that algebra, chosen by ``backend``:

- ``numba`` (the default for CPU tensors): one fused, compiled loop over the pixels
  (:func:`_numba_kernel`, numba ``parallel=True`` over image rows, the inner loop vectorised),
  which reads each depth once and writes each output once: about 1.5-2x the torch path on 2 cores,
  and insensitive to other load because it has no per-op thread synchronisation. Compiled on first
  use and cached on disk (``NUMBA_CACHE_DIR`` moves the cache).
- ``torch`` (:func:`_synthesize_torch`): the same steps as element-wise torch ops over chunks (any
  device, e.g. a GPU).

Bit-exactness: every pixel is computed independently, so results do not depend on the chunking or
the thread count; they are the same for the same build (:mod:`gen.shards` relies on it for
byte-identical shards). The two backends agree to ~1e-4 px and on every validity decision but knife
edges; the plain NumPy reference is :mod:`gen.flow_reference`; both agree with it to ~1e-4 px.
"""
from __future__ import annotations

import threading
from typing import Any, Callable

import numpy as np
import torch

from deepslam.core.camera import PinholeCamera

CHUNK_PIXELS = 1 << 18
"""Pixels per chunk of the fast path (262,144: 1 MB per float32 temporary, so they stay in cache)."""

_INV_SCALE = 2.0 ** 100
_INV_SCALE_RECIP = 2.0 ** -100

DEFAULT_OCCLUSION_REL_TOL = 0.02
"""Relative part of the z-buffer margin: a moved point is hidden when a point nearer by more than
``tol * depth_z1`` + its own depth change to the next pixel lands on its pixel (see
:func:`visible_after_motion`)."""


# ------------------------------------------------------------------------------------------------ inputs

def intrinsics_array(camera: Any, batch: int, width: int, height: int) -> np.ndarray:
    """(B, 4) float64 ``fx, fy, cx, cy`` (pixels) from a PinholeCamera or a (4,)/(B, 4) array/tensor.

    A PinholeCamera must have the depth map's size; raw intrinsics are taken to be at that size.
    """
    if isinstance(camera, PinholeCamera):
        if (camera.width, camera.height) != (width, height):
            raise ValueError(f"camera is {camera.width}x{camera.height} but the depth maps are {width}x{height}; "
                             "use camera.scaled(width, height)")
        k = camera.intrinsics()[None]
    else:
        if isinstance(camera, torch.Tensor):
            camera = camera.detach().cpu().double().numpy()
        k = np.asarray(camera, dtype=np.float64)
        if k.shape == (4,):
            k = k[None]
        if k.ndim != 2 or k.shape[1] != 4:
            raise ValueError(f"intrinsics must be a PinholeCamera, (4,) or (B, 4) fx, fy, cx, cy; got shape {k.shape}")
    if k.shape[0] == 1:
        k = np.repeat(k, batch, axis=0)
    if k.shape[0] != batch:
        raise ValueError(f"{k.shape[0]} intrinsics for a batch of {batch}")
    if not (np.isfinite(k).all() and (k[:, :2] > 0).all()):
        raise ValueError("intrinsics must be finite with positive focal lengths")
    return k


def _motions(cam1_from_cam0: Any, batch: int) -> np.ndarray:
    if isinstance(cam1_from_cam0, torch.Tensor):
        cam1_from_cam0 = cam1_from_cam0.detach().cpu().double().numpy()
    t = np.asarray(cam1_from_cam0, dtype=np.float64)
    if t.shape == (4, 4):
        t = np.broadcast_to(t, (batch, 4, 4))
    if t.shape != (batch, 4, 4):
        raise ValueError(f"cam1_from_cam0 must be (4, 4) or ({batch}, 4, 4), got {t.shape}")
    return t


def _depth_tensor(depth_z: Any) -> tuple[torch.Tensor, bool]:
    """(B, H, W) float32 contiguous tensor and whether the input was a single (H, W) map."""
    if isinstance(depth_z, np.ndarray):
        depth_z = torch.from_numpy(np.ascontiguousarray(depth_z, dtype=np.float32))
    elif not isinstance(depth_z, torch.Tensor):
        raise TypeError(f"depth_z must be a torch.Tensor or numpy array, got {type(depth_z).__name__}")
    single = depth_z.ndim == 2
    if single:
        depth_z = depth_z[None]
    if depth_z.ndim != 3:
        raise ValueError(f"depth_z must be (B, H, W) or (H, W), got {tuple(depth_z.shape)}")
    return depth_z.to(torch.float32).contiguous(), single


def projection_coefficients(k: np.ndarray, cam1_from_cam0: np.ndarray) -> np.ndarray:
    """(B, 3, 4) float64 ``M = [K R K^-1 | K t]``: rows give (nu, nv, d) = ``depth_z1 / depth_z`` times
    (u1, v1, 1) as ``M @ (u, v, 1, 1 / depth_z)``."""
    b = len(k)
    kmat = np.zeros((b, 3, 3))
    kmat[:, 0, 0], kmat[:, 1, 1], kmat[:, 0, 2], kmat[:, 1, 2], kmat[:, 2, 2] = k[:, 0], k[:, 1], k[:, 2], k[:, 3], 1.0
    kinv = np.zeros((b, 3, 3))
    kinv[:, 0, 0], kinv[:, 1, 1] = 1.0 / k[:, 0], 1.0 / k[:, 1]
    kinv[:, 0, 2], kinv[:, 1, 2], kinv[:, 2, 2] = -k[:, 2] / k[:, 0], -k[:, 3] / k[:, 1], 1.0
    m = np.empty((b, 3, 4))
    m[:, :, :3] = kmat @ cam1_from_cam0[:, :3, :3] @ kinv
    m[:, :, 3] = np.einsum("bij,bj->bi", kmat, cam1_from_cam0[:, :3, 3])
    return m


# --------------------------------------------------------------------------------------------- workspace

class _Workspace(threading.local):
    """Per-thread scratch buffers, reused between calls (fresh multi-MB allocations cost page faults)."""

    def __init__(self):
        self.buffers: dict[tuple, Any] = {}

    def cached(self, key: tuple, make: Callable[[], Any]) -> Any:
        """The buffers stored under ``key``, made by ``make()`` the first time (at most 9 kinds are kept:
        a tenth clears them all)."""
        if key not in self.buffers:
            if len(self.buffers) > 8:
                self.buffers.clear()
            self.buffers[key] = make()
        return self.buffers[key]

    def get(self, device: torch.device, n: int, h: int, w: int) -> dict[str, torch.Tensor]:
        """The torch path's float32 scratch for n samples of H x W."""
        def make() -> dict[str, torch.Tensor]:
            f32 = dict(dtype=torch.float32, device=device)
            return {"p": torch.empty(n, 3, h, w, **f32), "w": torch.empty(n, h, w, **f32),
                    "b": torch.empty(n, h, w, **f32), "t": torch.empty(n, h, w, **f32),
                    "ab": torch.empty(n, 2, h, w, **f32)}

        return self.cached((str(device), n, h, w), make)

    def depth1(self, device: torch.device, n: int, h: int, w: int) -> torch.Tensor:
        """A reused (n, H, W) float32 buffer for the moved points' depths."""
        return self.cached(("depth1", str(device), n, h, w),
                           lambda: torch.empty(n, h, w, dtype=torch.float32, device=device))


_WS = _Workspace()


# ------------------------------------------------------------------------------------------ numba kernel

_FASTMATH = {"contract", "arcp", "reassoc", "afn"}
"""LLVM fast-math flags of both kernels: fused multiply-add, reciprocals and reassociation (the plain
synthesis runs 1.2-1.3x faster with them); NOT ``nnan``/``ninf``, because the kernels test for NaN and
inf. The z-buffer kernel takes the same flags because its projection must give the plain kernel's
bits; its decisions are tested equal to :func:`visible_after_motion` (torch), bit for bit, on boxes,
holes, borders and large motions."""
_KERNEL = None
_PROJECT_ROW = None
_KERNEL_LOCK = threading.Lock()


def _numba_kernel():
    """The compiled kernel (compiled on first use; None where numba cannot be imported)."""
    global _KERNEL, _PROJECT_ROW
    if _KERNEL is None:
        try:
            import numba  # deferred: numba (~0.2 s) loads only when a kernel is first compiled
        except ImportError:  # pragma: no cover - numba is a dependency; the torch path still works
            _KERNEL = False
            return None
        # GNU OpenMP (numba's "omp" layer) breaks fork() (DataLoader workers, multiprocessing): take a
        # fork-safe layer (TBB if installed, else numba's own workqueue, which is not thread-safe: the
        # calls are serialised by _KERNEL_LOCK).
        if numba.config.THREADING_LAYER == "default":
            numba.config.THREADING_LAYER = "forksafe"

        @numba.njit(inline="always")
        def project_row(z, coef, flow, valid, depth1, b, v, bd1, want_depth1, cu, cv, half_w, half_h):  # pragma: no cover - compiled
            """Row v of sample b: flow[b, :, v], valid[b, v] and (when asked) depth_z1 into depth1[bd1, v],
            from z[b, v] and the sample's (3, 4) coefficients coef[b]. Shared by the plain and the
            z-buffer kernels, so that both write the same bits; inlined (a compiled call kept the loop
            scalar: 4x slower) and so compiled with its caller's fast-math flags."""
            w = z.shape[2]
            c = coef[b]
            one, zero, inf = np.float32(1.0), np.float32(0.0), np.float32(np.inf)
            fv = np.float32(v)
            bu = c[0, 1] * fv + c[0, 2]
            bv = c[1, 1] * fv + c[1, 2]
            bd = c[2, 1] * fv + c[2, 2]
            au, av, ad = c[0, 0], c[1, 0], c[2, 0]
            eu, ev, ed = c[0, 3], c[1, 3], c[2, 3]
            gv = np.float32(cv) - fv
            for u in range(w):
                zz = z[b, v, u]
                fu = np.float32(u)
                ok = (zz > zero) & (zz < inf)                       # 0, negative, NaN, inf: no depth
                iw = one / zz if ok else zero                      # w = 1 / depth_z
                nu = au * fu + bu + eu * iw
                nv = av * fu + bv + ev * iw
                d = ad * fu + bd + ed * iw                         # depth_z1 / depth_z
                ok = ok & (max(abs(nu), abs(nv)) < d)              # in front and inside the image
                rd = one / d if ok else zero
                flow[b, 0, v, u] = nu * rd * np.float32(half_w) + (np.float32(cu) - fu) if ok else zero
                flow[b, 1, v, u] = nv * rd * np.float32(half_h) + gv if ok else zero
                valid[b, v, u] = ok
                if want_depth1:
                    depth1[bd1, v, u] = d * zz if ok else zero

        @numba.njit(parallel=True, fastmath=_FASTMATH)
        def kernel(z, coef, flow, valid, depth1, want_depth1, cu, cv, half_w, half_h):  # pragma: no cover - compiled
            b_n, h, w = z.shape
            for r in numba.prange(b_n * h):
                b = r // h
                v = r - b * h
                project_row(z, coef, flow, valid, depth1, b, v, b, want_depth1, cu, cv, half_w, half_h)

        _PROJECT_ROW = project_row
        _KERNEL = kernel
    return _KERNEL or None


_ZB_KERNEL = None


def _zbuffer_kernel():
    """The plain synthesis and the z-buffer test of :func:`visible_after_motion` in one compiled kernel
    (numba; None where it is missing). The samples are split into one chunk per thread; each thread
    works through its samples in its own cache-sized scratch, so a sample's flow is tested while it is
    still in cache: (1) the sample's rows synthesized by the plain kernel's own row (``project_row``,
    inlined: the same bits), then row by row copied into three-row windows of landing points and
    depths, NaN-bordered (NaN = not valid), (2) the footprint half-widths and depth margins in
    branch-free row loops (they vectorise),
    (3) each point's nearest pixel and whether its footprint reaches a neighbour, (4) the nearest-pixel
    splat, branch-free, listing the points that reach further, (5) their splats into the 3x3 block,
    (6) the test, clearing ``valid``, ``flow`` and ``depth1`` where a point is hidden. Fast-math flags
    as the plain kernel's (:data:`_FASTMATH`)."""
    global _ZB_KERNEL
    if _ZB_KERNEL is None:
        if _numba_kernel() is None:  # also sets the fork-safe threading layer
            _ZB_KERNEL = False
            return None
        import numba  # deferred: numba (~0.2 s) loads only when a kernel is first compiled

        @numba.njit(inline="always")
        def msd(left, c, right):  # pragma: no cover - compiled
            """min one-sided |difference| of c to its neighbours (NaN = not valid or outside the image,
            then inf; 1 where no valid neighbour), as _min_one_sided_abs_diff."""
            inf = np.float32(np.inf)
            a = abs(c - left)
            b = abs(right - c)
            a = a if a == a else inf
            b = b if b == b else inf
            m = a if a < b else b
            return np.float32(1.0) if m == inf else m

        project_row = _PROJECT_ROW

        @numba.njit(parallel=True, fastmath=_FASTMATH)
        def kernel(z, coef, flow, valid, depth1, want_depth1, cu, cv, half_w, half_h, tol, n_chunks,
                   windows, flat, centres, lists, d1scratch):  # pragma: no cover - compiled
            b_n, _, h, w = flow.shape
            nan, inf = np.float32(np.nan), np.float32(np.inf)
            half, one_half, one, zero = np.float32(0.5), np.float32(1.5), np.float32(1.0), np.float32(0.0)
            ftol = np.float32(tol)
            hw = h * w
            per = (b_n + n_chunks - 1) // n_chunks
            for t in numba.prange(n_chunks):
                # Per-thread scratch, taken once (the row loops index it, they do not slice it).
                # Rolling windows of three rows of landing points and depths (slot r % 3 holds row r;
                # slot 3 stays NaN: the rows above and below the image), NaN-bordered left and right.
                xw, yw, zw = windows[t, 0], windows[t, 1], windows[t, 2]
                rxr, ryr, sla, zbuf = flat[t, 0], flat[t, 1], flat[t, 2], flat[t, 3]
                centre = centres[t]
                lst = lists[t]
                z1s = d1scratch[t]  # (H, W) depth_z1 of the sample, 0 where not valid
                xw[:] = nan
                yw[:] = nan
                zw[:] = nan
                for b in range(t * per, min(b_n, (t + 1) * per)):
                    zbuf[:] = inf
                    # (1) the plain synthesis of this sample (the same compiled row as the plain kernel)
                    for r in range(h):
                        project_row(z, coef, flow, valid, d1scratch, b, r, t, True, cu, cv, half_w, half_h)
                    for v in range(-1, h):
                        r = v + 1
                        if r < h:  # row v + 1 into the windows; one source array per loop (they vectorise)
                            k = r % 3
                            fr = np.float32(r)
                            for u in range(w):
                                xw[k, u + 1] = flow[b, 0, r, u] + np.float32(u) if valid[b, r, u] else nan
                            for u in range(w):
                                yw[k, u + 1] = flow[b, 1, r, u] + fr if valid[b, r, u] else nan
                            for u in range(w):
                                zw[k, u + 1] = z1s[r, u] if valid[b, r, u] else nan
                        if v < 0:
                            continue
                        q = v * w
                        ka, kc, kb = (v - 1) % 3 if v > 0 else 3, v % 3, r % 3 if r < h else 3
                        # (2) footprint half-widths and depth margins from rows v - 1, v, v + 1 (window
                        # column u + 1 is pixel u: non-negative indices only, the loop vectorises)
                        for u in range(w):
                            rr = half * (msd(xw[kc, u], xw[kc, u + 1], xw[kc, u + 2]) + msd(xw[ka, u + 1], xw[kc, u + 1], xw[kb, u + 1]))
                            rxr[u] = min(max(rr, half), one_half)
                            rr = half * (msd(yw[kc, u], yw[kc, u + 1], yw[kc, u + 2]) + msd(yw[ka, u + 1], yw[kc, u + 1], yw[kb, u + 1]))
                            ryr[u] = min(max(rr, half), one_half)
                            sla[q + u] = (msd(zw[kc, u], zw[kc, u + 1], zw[kc, u + 2]) + msd(zw[ka, u + 1], zw[kc, u + 1], zw[kb, u + 1])
                                          + ftol * zw[kc, u + 1])
                        # (3) nearest pixel of each landing point (h * w: not valid, a spare cell), and whether
                        # its footprint box holds another pixel centre (then the sign bit is set)
                        for u in range(w):
                            x, y = xw[kc, u + 1], yw[kc, u + 1]
                            xr, yr = np.rint(x), np.rint(y)
                            ok = x == x
                            xn = min(max(int(xr if ok else zero), 0), w - 1)
                            yn = min(max(int(yr if ok else zero), 0), h - 1)
                            alone = (one - abs(x - xr) > rxr[u]) & (one - abs(y - yr) > ryr[u])
                            centre[q + u] = (yn * w + xn if alone else ~(yn * w + xn)) if ok else hw
                        n = 0
                        for u in range(w):  # (4) nearest pixels, branch-free; the other points listed
                            c = centre[q + u]
                            lst[n] = u
                            n += c < 0
                            c = c if c >= 0 else ~c
                            z1 = zw[kc, u + 1]
                            old = zbuf[c]
                            zbuf[c] = z1 if z1 < old else old  # NaN (not valid: the spare cell) never writes
                        for k2 in range(n):  # (5) the footprints that reach into the 3x3 block
                            u = lst[k2]
                            c = ~centre[q + u]
                            centre[q + u] = c
                            z1 = zw[kc, u + 1]
                            x, y = xw[kc, u + 1], yw[kc, u + 1]
                            xr, yr = np.rint(x), np.rint(y)
                            rx, ry = rxr[u], ryr[u]
                            dx, dy = x - xr, y - yr
                            xn = min(max(int(xr), 0), w - 1)
                            yn = min(max(int(yr), 0), h - 1)
                            xp_ = (one - dx <= rx) & (xn + 1 < w)
                            xm_ = (one + dx <= rx) & (xn > 0)
                            yp_ = (one - dy <= ry) & (yn + 1 < h)
                            ym_ = (one + dy <= ry) & (yn > 0)
                            if (xp_ & xm_) | (yp_ & ym_):  # a footprint wider than two pixels (rare)
                                # the eight neighbours, branch-free: an unselected one is written back as
                                # read (at a clamped index; each thread owns its z-buffer)
                                for kx, ky, sel in ((1, 0, xp_), (-1, 0, xm_), (0, 1, yp_), (0, -1, ym_),
                                                    (1, 1, xp_ & yp_), (-1, 1, xm_ & yp_), (1, -1, xp_ & ym_),
                                                    (-1, -1, xm_ & ym_)):
                                    t2 = min(max(c + ky * w + kx, 0), hw)
                                    old = zbuf[t2]
                                    zbuf[t2] = z1 if (sel & (z1 < old)) else old
                            else:
                                # at most one neighbour per axis: that column, that row and their corner;
                                # an axis without one writes to the point's own pixel again (a no-op min)
                                kx = np.int64(xp_) - np.int64(xm_)
                                ky = (np.int64(yp_) - np.int64(ym_)) * w
                                t2 = c + kx
                                old = zbuf[t2]
                                zbuf[t2] = z1 if z1 < old else old
                                t2 = c + ky
                                old = zbuf[t2]
                                zbuf[t2] = z1 if z1 < old else old
                                t2 = c + ky + kx
                                old = zbuf[t2]
                                zbuf[t2] = z1 if z1 < old else old
                    for v in range(h):  # (6) the test: clear what is hidden
                        q = v * w
                        m = 0
                        for u in range(w):  # branch-free; the rare hidden points are cleared after
                            c = centre[q + u]
                            hid = (c != hw) & (not (z1s[v, u] - zbuf[c] <= sla[q + u]))  # valid and hidden
                            lst[u] = hid
                            m += hid
                        if m:
                            for u in range(w):
                                if lst[u]:
                                    valid[b, v, u] = False
                                    flow[b, 0, v, u] = zero
                                    flow[b, 1, v, u] = zero
                                    z1s[v, u] = zero
                    if want_depth1:
                        depth1[b] = z1s

        _ZB_KERNEL = kernel
    return _ZB_KERNEL or None

def _zbuffer_scratch(n_chunks: int, h: int, w: int) -> tuple[np.ndarray, ...]:
    """The numba z-buffer's per-thread scratch (reused): (n, 3, 4, W + 2) float32 rolling windows of
    landing points (x, y) and depths, NaN-bordered; (n, 4, H * W + 1) float32: one row's footprint
    radii (x, y), the depth margins, the z-buffer (with a spare cell for points that are not valid);
    (n, H * W) int32 nearest pixels; (n, W) int32 one row's list of points whose footprint reaches a
    neighbour (then its hidden points); (n, H, W) float32 the sample's depth_z1."""
    return _WS.cached(("zb", n_chunks, h, w), lambda: (np.empty((n_chunks, 3, 4, w + 2), np.float32),
                                                     np.empty((n_chunks, 4, h * w + 1), np.float32),
                                                     np.empty((n_chunks, h * w), np.int32),
                                                     np.empty((n_chunks, w), np.int32),
                                                     np.empty((n_chunks, h, w), np.float32)))


def _numba_threads() -> int:
    """Set numba's thread count to torch's (at most numba's pool) and return it; call under
    :data:`_KERNEL_LOCK`."""
    import numba  # deferred: numba (~0.2 s) loads only when a kernel is first compiled

    n = max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    return n


def _kernel_args(z: torch.Tensor, mn: np.ndarray, flow_chw: torch.Tensor, valid: torch.Tensor,
                 depth1: torch.Tensor | None) -> tuple:
    """The arguments both compiled kernels start with: zero-copy numpy views of the CPU tensors (a
    (1, 1, 1) dummy for an unwanted depth_z1), the float32 coefficients and the image centre and
    half-size."""
    _, h, w = z.shape
    d1 = depth1.numpy() if depth1 is not None else np.empty((1, 1, 1), np.float32)
    return (z.numpy(), np.ascontiguousarray(mn, dtype=np.float32), flow_chw.numpy(), valid.numpy(), d1,
            depth1 is not None, (w - 1) / 2.0, (h - 1) / 2.0, w / 2.0, h / 2.0)


def _synthesize_numba(z: torch.Tensor, mn: np.ndarray, flow_chw: torch.Tensor, valid: torch.Tensor,
                      depth1: torch.Tensor | None) -> None:
    """The plain compiled kernel on CPU tensors, as many threads as torch uses."""
    kernel = _numba_kernel()
    with _KERNEL_LOCK:
        _numba_threads()
        kernel(*_kernel_args(z, mn, flow_chw, valid, depth1))


def _synthesize_zbuffer_numba(z: torch.Tensor, mn: np.ndarray, flow_chw: torch.Tensor, valid: torch.Tensor,
                              depth1: torch.Tensor | None, occlusion_rel_tol: float) -> None:
    """The plain synthesis and the z-buffer test in one compiled pass per sample (CPU tensors, one
    chunk of samples per thread): each sample's flow is tested while it is still in cache."""
    kernel = _zbuffer_kernel()
    bsz, h, w = z.shape
    with _KERNEL_LOCK:
        n_chunks = min(_numba_threads(), bsz)
        kernel(*_kernel_args(z, mn, flow_chw, valid, depth1), float(occlusion_rel_tol), n_chunks,
               *_zbuffer_scratch(n_chunks, h, w))


def _synthesize_torch(z: torch.Tensor, mn: np.ndarray, flow_chw: torch.Tensor, valid: torch.Tensor,
                      depth1: torch.Tensor | None) -> None:
    """The same algebra as element-wise torch ops over chunks of about :data:`CHUNK_PIXELS` pixels
    (any device), with reused scratch buffers."""
    bsz, h, w = z.shape
    device = z.device
    cu, cv = (w - 1) / 2.0, (h - 1) / 2.0
    us, vs = np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)
    f32 = dict(dtype=torch.float32, device=device)
    row = torch.as_tensor(mn[:, :, 0, None] * us, **f32).unsqueeze(2)                     # (B, 3, 1, W)
    col = torch.as_tensor(mn[:, :, 1, None] * vs + mn[:, :, 2, None], **f32).unsqueeze(3)  # (B, 3, H, 1)
    # The translation column meets w = 1 / depth_z scaled by 2^100 (exact: a power of two), so that a
    # single clamp d <= 2^100 w rejects depth_z <= 0 and depth_z = inf (2^100 w <= 0) while leaving
    # every sane depth alone (2^100 w > 1e24 > d for depth_z < 1e6 m); depth_z below 4e-9 m gives inf.
    e4 = torch.as_tensor(mn[:, :, 3] * _INV_SCALE_RECIP, **f32).view(bsz, 3, 1, 1)
    scale = torch.tensor(_INV_SCALE, **f32)
    gu = torch.as_tensor(cu - us, **f32).view(1, 1, w)
    gv = torch.as_tensor(cv - vs, **f32).view(1, h, 1)
    chunk = max(1, min(bsz, CHUNK_PIXELS // (h * w)))
    ws = _WS.get(device, chunk, h, w)
    for s in range(0, bsz, chunk):
        n = min(chunk, bsz - s)
        sl = slice(s, s + n)
        inv = ws["w"][:n]
        tt = ws["t"][:n]
        bb = ws["b"][:n]
        ab = ws["ab"][:n]
        p = ws["p"][:n]
        torch.div(scale, z[sl], out=inv)                       # 2^100 w = 2^100 / depth_z
        torch.add(row[sl], col[sl], out=p)                     # M[:, :, :3] @ (u, v, 1)
        p.addcmul_(e4[sl], inv.unsqueeze(1))                   # + (2^-100 M[:, :, 3]) (2^100 w)
        d = p[:, 2]                                            # depth_z1 / depth_z
        if depth1 is not None:
            torch.mul(d, z[sl], out=depth1[sl])
        d.clamp_(max=inv)                                      # depth_z <= 0 or inf: d <= 0 (NaN stays)
        torch.abs(p[:, :2], out=ab)                            # |nu|, |nv|
        torch.maximum(ab[:, 0], ab[:, 1], out=bb)              # NaN propagates
        torch.lt(bb, d, out=tt)                                # |s_u|, |s_v| < 1 and d > 0: 1.0, else 0.0
        valid[sl].copy_(tt)
        d.mul_(tt).reciprocal_()                               # 1 / d; not valid -> inf (or NaN)
        torch.addcmul(gu, p[:, 0], d, value=w / 2.0, out=ab[:, 0])  # u1 - u = (nu / d) W/2 + (cx_img - u)
        torch.addcmul(gv, p[:, 1], d, value=h / 2.0, out=ab[:, 1])
        torch.nan_to_num(ab, 0.0, 0.0, 0.0, out=flow_chw[sl])  # inf / NaN where not valid -> 0; one write


# ------------------------------------------------------------------------------------------------- API

BACKENDS = ("auto", "numba", "torch")
"""Implementations of :func:`synthesize` (see the module docstring)."""


def synthesize(depth_z: Any, camera: Any, cam1_from_cam0: Any, zbuffer: bool = False, *,
               occlusion_rel_tol: float = DEFAULT_OCCLUSION_REL_TOL,
               out: tuple[torch.Tensor, torch.Tensor] | None = None,
               return_depth1: bool = False, backend: str = "auto"):
    """Flow that the motion ``cam1_from_cam0`` causes on a static scene seen with ``depth_z`` in frame 0.

    Args:
        depth_z: (B, H, W) (or (H, W)) float32 torch tensor (any device) or numpy array: depth along the
            optical axis of camera 0, metres. 0, negative, NaN and inf mean "no depth".
        camera: a :class:`core.camera.PinholeCamera` of size W x H, or intrinsics ``fx, fy, cx, cy``
            (pixels, at this resolution) as a (4,) or (B, 4) array/tensor (per-sample cameras).
        cam1_from_cam0: (B, 4, 4) or (4, 4) rigid transforms (torch or numpy, float64 preferred; metres,
            OpenCV axes) mapping points of camera 0 into camera 1.
        zbuffer: also mark pixels hidden in frame 1 by a nearer moved point as invalid: the moved points'
            depths are splatted into frame 1 (each over its own moved footprint) with
            ``scatter_reduce(amin)``, and a point is hidden when the minimum at its nearest pixel is
            nearer than its own depth by more than a margin (:func:`visible_after_motion`; on the CPU
            the same test compiled with numba and fused with the synthesis, about seven times the
            cost of the plain synthesis: ``python -m bench.run --only gen``).
        occlusion_rel_tol: see :data:`DEFAULT_OCCLUSION_REL_TOL`.
        out: optional ``(flow_chw, valid)`` buffers to write into and reuse across calls: (B, 2, H, W)
            float32 and (B, H, W) bool, contiguous, on the depth's device. A fresh 30 MB result costs
            about as much to allocate (page faults) as it costs to compute, so loops should pass this.
        return_depth1: also return (B, H, W) float32 ``depth_z1``, the moved point's depth in camera 1
            (0 where not valid).
        backend: ``numba`` (fused compiled loop, CPU), ``torch`` (element-wise torch ops, any device) or
            ``auto`` (numba for CPU tensors when it is installed, else torch).

    Returns:
        ``(flow, valid)`` (and ``depth_z1`` when asked): flow (B, H, W, 2) float32 pixels, ``flow[b, v, u]
        = (du, dv)``, 0 where not valid; valid (B, H, W) bool. ``flow`` is a permuted view of
        channels-first storage: ``flow.permute(0, 3, 1, 2)`` is the contiguous (B, 2, H, W) tensor a network
        wants, at no cost; call ``.contiguous()`` for an interleaved copy. An (H, W) input gives (H, W, 2)
        and (H, W). Not differentiable (runs under ``torch.no_grad``).
    """
    z, single = _depth_tensor(depth_z)
    bsz, h, w = z.shape
    device = z.device
    k = intrinsics_array(camera, bsz, w, h)
    m = projection_coefficients(k, _motions(cam1_from_cam0, bsz))
    # Re-centre/scale the image rows so that they give s = 2 (u1 - cx_img) / W (and v) directly.
    cu, cv = (w - 1) / 2.0, (h - 1) / 2.0
    mn = m.copy()
    mn[:, 0] = (m[:, 0] - cu * m[:, 2]) * (2.0 / w)
    mn[:, 1] = (m[:, 1] - cv * m[:, 2]) * (2.0 / h)
    f32 = dict(dtype=torch.float32, device=device)
    if out is None:
        flow_chw = torch.empty(bsz, 2, h, w, **f32)
        valid = torch.empty(bsz, h, w, dtype=torch.bool, device=device)
    else:
        flow_chw, valid = out
        if (tuple(flow_chw.shape) != (bsz, 2, h, w) or flow_chw.dtype != torch.float32
                or tuple(valid.shape) != (bsz, h, w) or valid.dtype != torch.bool
                or not flow_chw.is_contiguous() or not valid.is_contiguous()
                or flow_chw.device != device or valid.device != device):
            raise ValueError(f"out must be ((B, 2, H, W) float32, (B, H, W) bool) contiguous on {device} "
                             f"for B, H, W = {bsz}, {h}, {w}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    use_numba = backend == "numba" or (backend == "auto" and device.type == "cpu" and _numba_kernel() is not None)
    if use_numba and device.type != "cpu":
        raise ValueError("the numba backend runs on CPU tensors only; use backend='torch'")
    fused = zbuffer and use_numba and _zbuffer_kernel() is not None  # one compiled pass: synthesis + z-buffer
    if return_depth1:
        depth1 = torch.empty(bsz, h, w, **f32)
    elif zbuffer and not fused:  # scratch only: reused (a fresh buffer costs page faults)
        depth1 = _WS.depth1(device, bsz, h, w)
    else:
        depth1 = None

    with torch.no_grad():
        if fused:
            _synthesize_zbuffer_numba(z, mn, flow_chw, valid, depth1, occlusion_rel_tol)
        else:
            (_synthesize_numba if use_numba else _synthesize_torch)(z, mn, flow_chw, valid, depth1)
        if zbuffer and not fused:
            visible = visible_after_motion(flow_chw, valid, depth1, occlusion_rel_tol)
            hidden = valid & ~visible
            valid.copy_(visible)
            flow_chw.masked_fill_(hidden.unsqueeze(1), 0.0)
        if depth1 is not None and not use_numba:  # the numba kernels write 0 where not valid
            depth1.masked_fill_(~valid, 0.0)

    flow = flow_chw.permute(0, 2, 3, 1)
    if single:
        flow, valid = flow[0], valid[0]
        depth1 = None if depth1 is None else depth1[0]
    return (flow, valid, depth1) if return_depth1 else (flow, valid)


def _min_one_sided_abs_diff(a: torch.Tensor, dim: int) -> torch.Tensor:
    """Per pixel, the smaller of |forward| and |backward| difference of ``a`` (NaN = not valid) along
    ``dim``; 1 where neither neighbour is valid. The smaller side is the within-surface one at a depth
    edge, so an edge next door does not inflate it."""
    n = a.shape[dim]
    if n < 2:
        return torch.ones_like(a)
    inf = float("inf")
    diff = (a.narrow(dim, 1, n - 1) - a.narrow(dim, 0, n - 1)).abs_().nan_to_num_(inf, inf, inf)
    out = torch.empty_like(a)
    out.narrow(dim, 0, 1).copy_(diff.narrow(dim, 0, 1))
    out.narrow(dim, n - 1, 1).copy_(diff.narrow(dim, n - 2, 1))
    if n > 2:
        torch.minimum(diff.narrow(dim, 1, n - 2), diff.narrow(dim, 0, n - 2), out=out.narrow(dim, 1, n - 2))
    return out.nan_to_num_(1.0, 1.0, 1.0)


def visible_after_motion(flow_chw: torch.Tensor, valid: torch.Tensor, depth_z1: torch.Tensor,
                         occlusion_rel_tol: float = DEFAULT_OCCLUSION_REL_TOL) -> torch.Tensor:
    """z-buffer test in frame 1 for the moved points of each depth map.

    Args:
        flow_chw: (B, 2, H, W) float32 flow in pixels (channels first).
        valid: (B, H, W) bool, points that land inside frame 1 in front of the camera.
        depth_z1: (B, H, W) float32 depth of each moved point in camera 1, metres.
        occlusion_rel_tol: relative part of the depth margin (see below).

    Returns:
        (B, H, W) bool: True where the point is valid and not hidden.

    Each valid point splats its depth (``scatter_reduce`` amin) onto its nearest pixel and onto every
    other pixel centre of the 3x3 block around it that lies inside the bounding box of its own moved
    footprint: the unit square of the source pixel maps (to first order)
    to a parallelogram with edges d(x1, y1)/du and d(x1, y1)/dv, whose box has half-widths
    ``0.5 (|dx1/du| + |dx1/dv|)`` and ``0.5 (|dy1/du| + |dy1/dv|)``, clamped to [0.5, 1.5] px (half a
    pixel for a rigid shift, so a foreground edge never hides the background pixel beside it; more
    where the motion magnifies a surface, so that it leaves no holes for farther points to show
    through). A point is hidden when the minimum at its nearest pixel is nearer than its own depth by
    more than ``tol * depth_z1 + |d depth_z1/du| + |d depth_z1/dv|``: the second part is the depth change
    to the neighbouring source pixels, which may land on the same target pixel when the surface
    shrinks in the new view (a road seen at a grazing angle) without hiding anything. Derivatives are
    the smaller one-sided differences (:func:`_min_one_sided_abs_diff`).
    """
    bsz, _, h, w = flow_chw.shape
    dev = flow_chw.device
    if not bool(valid.any()):
        return torch.zeros_like(valid)
    uu = torch.arange(w, dtype=torch.float32, device=dev).view(1, 1, w)
    vv = torch.arange(h, dtype=torch.float32, device=dev).view(1, h, 1)
    nan = torch.tensor(float("nan"), device=dev)
    x1 = torch.where(valid, flow_chw[:, 0] + uu, nan)
    y1 = torch.where(valid, flow_chw[:, 1] + vv, nan)
    zz = torch.where(valid, depth_z1, nan)
    rx = (0.5 * (_min_one_sided_abs_diff(x1, 2) + _min_one_sided_abs_diff(x1, 1))).clamp_(0.5, 1.5)
    ry = (0.5 * (_min_one_sided_abs_diff(y1, 2) + _min_one_sided_abs_diff(y1, 1))).clamp_(0.5, 1.5)
    slack = _min_one_sided_abs_diff(zz, 2).add_(_min_one_sided_abs_diff(zz, 1)).add_(zz, alpha=occlusion_rel_tol)
    xn, yn = torch.round(x1), torch.round(y1)
    dx, dy = x1 - xn, y1 - yn                                 # in [-0.5, 0.5] (NaN where not valid)
    xn = xn.nan_to_num_(0.0).long().clamp_(0, w - 1)
    yn = yn.nan_to_num_(0.0).long().clamp_(0, h - 1)
    dummy = bsz * h * w                                       # invalid points splat into an extra cell
    base = torch.arange(bsz, device=dev).view(bsz, 1, 1) * (h * w)
    centre = torch.where(valid, base + yn * w + xn, dummy)
    zbuf = torch.full((dummy + 1,), float("inf"), dtype=torch.float32, device=dev)
    zbuf.scatter_reduce_(0, centre.reshape(-1), zz.reshape(-1), reduce="amin")  # nearest pixel
    # Neighbours in the 3x3 block that lie inside the point's footprint box (|k - d| <= r).
    in_x = {1: (1 - dx <= rx) & (xn + 1 < w), -1: (1 + dx <= rx) & (xn > 0)}
    in_y = {1: (1 - dy <= ry) & (yn + 1 < h), -1: (1 + dy <= ry) & (yn > 0)}
    for kx in (-1, 0, 1):
        for ky in (-1, 0, 1):
            if kx == 0 and ky == 0:
                continue
            m = in_x[kx] if ky == 0 else in_y[ky] if kx == 0 else in_x[kx] & in_y[ky]
            if bool(m.any()):  # NaN comparisons are False: only valid points
                zbuf.scatter_reduce_(0, torch.where(m, centre + (ky * w + kx), dummy).reshape(-1),
                                     zz.reshape(-1), reduce="amin")
    return valid & (zz - zbuf[centre] <= slack)


def normalize_flow(flow: Any, width: int, height: int, channel_axis: int = -1):
    """The paper's normalised flow: (du / W, dv / H). Works on numpy arrays and torch tensors.

    Args:
        flow: flow in pixels with the (du, dv) pair on ``channel_axis`` (-1 for (..., H, W, 2),
            1 or -3 for (B, 2, H, W)).
        width, height: the image size the flow was measured at, pixels.
    """
    scale_shape = [1] * flow.ndim
    scale_shape[channel_axis] = 2
    scale = np.array([1.0 / width, 1.0 / height], dtype=np.float32).reshape(scale_shape)
    if isinstance(flow, torch.Tensor):
        return flow * torch.as_tensor(scale, device=flow.device, dtype=flow.dtype)
    return np.asarray(flow) * scale.astype(np.asarray(flow).dtype)


def denormalize_flow(flow_norm: Any, width: int, height: int, channel_axis: int = -1):
    """Inverse of :func:`normalize_flow`: pixels from (du / W, dv / H)."""
    scale_shape = [1] * flow_norm.ndim
    scale_shape[channel_axis] = 2
    scale = np.array([width, height], dtype=np.float32).reshape(scale_shape)
    if isinstance(flow_norm, torch.Tensor):
        return flow_norm * torch.as_tensor(scale, device=flow_norm.device, dtype=flow_norm.dtype)
    return np.asarray(flow_norm) * scale.astype(np.asarray(flow_norm).dtype)


# ----------------------------------------------------------------------------------------------------
# flow as an estimator sees it: points leaving the image keep their flow (training inputs, not labels)


MISSING_DEPTH = ("infinity", "invalid")
"""What depth 0 (no surface, or unknown) means to :func:`synthesize_flow`."""


def synthesize_flow(depth_z: torch.Tensor, intrinsics: np.ndarray, cam1_from_cam0: np.ndarray,
                    missing_depth: str = "infinity", pool: int = 1,
                    chunk_pixels: int = 1 << 18) -> tuple[torch.Tensor, torch.Tensor]:
    """Flow of a static scene for a batch of depth maps and motions, KEEPING points that leave the image.

    The same algebra as :func:`synthesize` (its :func:`projection_coefficients`
    ``M = [K R K^-1 | K t]``; ``(u1, v1, 1) ~ M (u, v, 1, 1 / depth_z)``), but a point that lands
    outside frame 1 keeps its flow: an estimator such as DIS also reports (extrapolated) flow for
    pixels that leave the view, so zeroing them (the right thing for a flow *label*) would teach the
    network a pattern it never sees at test time. With ``missing_depth="infinity"`` a pixel without
    depth (sky in a render, 0 or non-finite) is a point at infinity and gets the rotation-only flow,
    as the simulator's ground-truth flow and any real estimator give it.

    Computed on the depth's device: on the CPU in chunks of about ``chunk_pixels`` pixels with in-place ops
    (the temporaries stay in cache, as in gen.flow), on a GPU in one chunk; optionally averaged over
    ``pool`` x ``pool`` blocks per chunk (:func:`pool_flow`).

    Args:
        depth_z: (B, H, W) float32 metres, 0 = none (a tensor on any device: the result is on the same one).
        intrinsics: (B, 4) fx, fy, cx, cy at H x W.
        cam1_from_cam0: (B, 4, 4) float64.
        missing_depth: ``infinity`` or ``invalid`` (flow 0, valid false).
        pool: average the result over pool x pool blocks (H, W multiples of pool).

    Returns:
        flow (B, 2, H/pool, W/pool) float32 px at the output grid (0 where invalid), valid
        (B, H/pool, W/pool) bool (the point is in front of camera 1, depth known unless ``infinity``;
        pooled: any pixel of the block valid).
    """
    if missing_depth not in MISSING_DEPTH:
        raise ValueError(f"missing_depth must be one of {MISSING_DEPTH}, got {missing_depth!r}")
    z_all = torch.as_tensor(depth_z, dtype=torch.float32)
    b, h, w = z_all.shape
    if h % pool or w % pool:
        raise ValueError(f"depth {h}x{w} is not a multiple of pool {pool}")
    f32 = dict(dtype=torch.float32, device=z_all.device)
    m = torch.as_tensor(projection_coefficients(np.asarray(intrinsics, np.float64).reshape(b, 4),
                                                np.asarray(cam1_from_cam0, np.float64).reshape(b, 4, 4)), **f32)
    u = torch.arange(w, **f32).view(1, 1, w)
    v = torch.arange(h, **f32).view(1, h, 1)
    flow_out = torch.empty(b, 2, h // pool, w // pool, **f32)
    valid_out = torch.empty(b, h // pool, w // pool, dtype=torch.bool, device=z_all.device)
    # a GPU wants one launch per op for the whole batch; a CPU wants the temporaries to stay in cache
    n_chunk = b if z_all.device.type != "cpu" else max(1, min(b, chunk_pixels // (h * w)))
    p = torch.empty(n_chunk, 3, h, w, **f32)
    inv = torch.empty(n_chunk, h, w, **f32)
    flow = torch.empty(n_chunk, 2, h, w, **f32)
    with torch.no_grad():
        for s in range(0, b, n_chunk):
            n = min(n_chunk, b - s)
            z, pp, iv, fl = z_all[s:s + n], p[:n], inv[:n], flow[:n]
            mm = m[s:s + n]
            torch.reciprocal(z, out=iv)
            iv.nan_to_num_(0.0, 0.0, 0.0).clamp_min_(0.0)  # 0 / negative / NaN / inf depth -> infinity
            torch.add(mm[:, :, 0, None, None] * u, mm[:, :, 1, None, None] * v + mm[:, :, 2, None, None], out=pp)
            pp.addcmul_(mm[:, :, 3].view(n, 3, 1, 1), iv.unsqueeze(1))
            d = pp[:, 2]
            valid = d > 1e-6
            if missing_depth == "invalid":
                valid &= iv > 0
            d.clamp_min_(1e-6).reciprocal_()
            torch.mul(pp[:, 0], d, out=fl[:, 0])
            fl[:, 0].sub_(u)
            torch.mul(pp[:, 1], d, out=fl[:, 1])
            fl[:, 1].sub_(v)
            fl.nan_to_num_(0.0, 0.0, 0.0)
            fl.mul_(valid.unsqueeze(1))
            if pool > 1:
                pooled, pv = pool_flow(fl, valid, pool, masked=True)
                flow_out[s:s + n] = pooled
                valid_out[s:s + n] = pv
            else:
                flow_out[s:s + n] = fl
                valid_out[s:s + n] = valid
    return flow_out, valid_out


def pool_flow(flow: torch.Tensor, valid: torch.Tensor, factor: int, masked: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Average flow (B, 2, H, W) px over ``factor`` x ``factor`` blocks, weighted by valid (B, H, W),
    and rescale its values by 1/factor (the coarser pixel grid). Returns ((B, 2, H/f, W/f), valid any).
    ``masked``: the flow is already 0 where not valid (saves a multiplication)."""
    if factor == 1:
        return (flow if masked else flow * valid[:, None]), valid
    v = valid[:, None].float()
    num = torch.nn.functional.avg_pool2d(flow if masked else flow * v, factor)
    den = torch.nn.functional.avg_pool2d(v, factor)
    out = torch.where(den > 0, num / den.clamp_min(1e-12), torch.zeros_like(num)) / factor
    return out, den[:, 0] > 0
