"""Frame-to-frame costs of Majkowska, Zordan & Faloutsos's hand/body splicing (SCA 2006, Sec. 4, Eqs. 6-9).

Pure tensor math (imports torch and math only). Markers are four points per frame in the paper's order: two on
the wrist (p1, p2), one on the forearm (p3), one on the hand (p4). World z is up (torchhand's convention; the
paper's y-up formulas are rewritten for z up: paper x = x, paper z = -y, the paper's R_y is R_z here).

Sign features (Eq. 6's ingredients)
    ``sign_features`` smooths each marker coordinate with a Gaussian of ``sigma`` seconds, takes central
    differences for velocity and acceleration and returns their signs with a dead zone. The paper gives no
    estimator; its Table 1 defines a hold as "a = 0, v = 0", which a raw sign of noisy data never yields, so a
    component counts as 0 when its magnitude is below ``dead_zone`` times the clip's 95th percentile of that
    magnitude (per marker and derivative; scale-free, so it survives amplitude differences). The horizontal
    threshold uses the horizontal speed (a yaw-invariant magnitude), so rotating a clip about z and then taking
    signs (Eq. 6 with Eq. 7's rotation) uses the same threshold in every direction.

Local yaw (Eq. 7, from Kovar et al. 2002)
    For body frame i and hand frame j, over windows of ``frames`` frames around each (clamped at the ends) and
    the K markers (N = K * frames points), with barred terms being sums:
    ``theta = atan2(S(y x') - S(x y') - (ybar xbar' - xbar ybar')/N, S(x x') + S(y y') - (xbar xbar' + ybar ybar')/N)``
    and ``R_z(theta)`` rotates the hand's vectors onto the body's. All (i, j) come from ``frames`` small matrix
    products per term.

Costs
    ``sign_cost(fp, fq)``: Eq. 6 with signs already in a common frame: ``sum_c (s_p[c] - s_q[c])^2`` over the
    24 sign channels, as one matrix product (values are integers 0..96).
    ``sign_cost_yaw(vp, vq, theta, ...)``: Eq. 6 literally, the hand's derivatives rotated by ``R_z(theta[i, j])``
    per cell before taking signs (the paper's mode; row blocks bound the memory).
    ``palm_cost(hp, hq)``: Eq. 9, the angle between hand vectors given in a common frame (the forearm frame of
    each clip, see torchhand.splice), radians.
"""

from __future__ import annotations

import math

import torch

__all__ = ["gaussian_smooth", "smooth_derivatives", "sign_features", "signs_from_derivatives", "window_yaw",
           "sign_cost",
           "sign_cost_yaw", "palm_cost", "forearm_hand_vectors"]


def gaussian_smooth(x: torch.Tensor, sigma_frames: float) -> torch.Tensor:
    """Gaussian smoothing along dim 1 of (B, T, ...) with edge replication; identity when sigma < 0.3 frames."""
    if sigma_frames < 0.3:
        return x
    r = max(1, int(math.ceil(3.0 * sigma_frames)))
    t = torch.arange(-r, r + 1, dtype=x.dtype, device=x.device)
    k = torch.exp(-0.5 * (t / sigma_frames) ** 2)
    k = k / k.sum()
    B, T = x.shape[:2]
    flat = x.reshape(B, T, -1).transpose(1, 2).reshape(-1, 1, T)            # (B*C, 1, T)
    padded = torch.nn.functional.pad(flat, (r, r), mode="replicate")
    out = torch.nn.functional.conv1d(padded, k.view(1, 1, -1))
    return out.reshape(B, -1, T).transpose(1, 2).reshape(x.shape)


def smooth_derivatives(x: torch.Tensor, fps: float, sigma: float = 0.05) -> tuple[torch.Tensor, torch.Tensor]:
    """Velocity and acceleration of marker tracks.

    Args:
        x: marker positions, (B, T, K, 3), metres
        fps: frames per second of the clip
        sigma: Gaussian smoothing, seconds (0 = none)

    Returns:
        v: (B, T, K, 3), metres/second; a: (B, T, K, 3), metres/second^2 (central differences, one-sided at the ends)
    """
    _check_markers(x, "x")
    xs = gaussian_smooth(x, sigma * fps)

    def diff(y: torch.Tensor) -> torch.Tensor:
        if y.shape[1] < 2:
            return torch.zeros_like(y)
        d = torch.empty_like(y)
        d[:, 1:-1] = (y[:, 2:] - y[:, :-2]) * (0.5 * fps)
        d[:, 0] = (y[:, 1] - y[:, 0]) * fps
        d[:, -1] = (y[:, -1] - y[:, -2]) * fps
        return d

    v = diff(xs)
    return v, diff(v)


def signs_from_derivatives(v: torch.Tensor, a: torch.Tensor, dead_zone: float = 0.05) -> torch.Tensor:
    """Signs of velocity and acceleration components with a scale-free dead zone (module docstring).

    Args:
        v, a: (B, T, K, 3) derivatives
        dead_zone: fraction of the clip's 95th percentile magnitude below which a component's sign is 0

    Returns:
        signs: (B, T, K, 6), int8 in {-1, 0, 1}: vx, vy, vz, ax, ay, az
    """
    out = []
    for d in (v, a):
        horiz = d[..., :2].norm(dim=-1)                                        # (B, T, K)
        th_h = dead_zone * torch.quantile(horiz, 0.95, dim=1, keepdim=True)    # (B, 1, K)
        th_z = dead_zone * torch.quantile(d[..., 2].abs(), 0.95, dim=1, keepdim=True)
        th = torch.stack([th_h, th_h, th_z], -1)                               # (B, 1, K, 3)
        s = torch.sign(d) * (d.abs() > th)
        out.append(s)
    return torch.cat(out, -1).to(torch.int8)


def sign_features(x: torch.Tensor, fps: float, sigma: float = 0.05, dead_zone: float = 0.05) -> torch.Tensor:
    """Eq. 6's sign features of marker tracks (module docstring).

    Args:
        x: marker positions, (B, T, K, 3), metres, z up
        fps: frames per second
        sigma: smoothing, seconds
        dead_zone: fraction of the 95th percentile magnitude counted as zero

    Returns:
        signs: (B, T, K, 6), int8
    """
    v, a = smooth_derivatives(x, fps, sigma)
    return signs_from_derivatives(v, a, dead_zone)


def window_yaw(P: torch.Tensor, Q: torch.Tensor, frames: int = 5) -> torch.Tensor:
    """Eq. 7 for every pair of frames: the yaw that best aligns hand windows onto body windows.

    Args:
        P: body markers, (B, n, K, 3), metres, z up (shoulder-relative in the paper)
        Q: hand markers, (B, m, K, 3), metres, z up
        frames: window length in frames (the paper: 5, with K = 4 markers: 20 points)

    Returns:
        theta: (B, n, m), radians: ``R_z(theta[b, i, j])`` rotates hand vectors near frame j onto body vectors
        near frame i
    """
    _check_markers(P, "P")
    _check_markers(Q, "Q")
    B, n, K, _ = P.shape
    m = Q.shape[1]
    half = frames // 2
    offs = range(-half, frames - half)
    ip = torch.arange(n, device=P.device)
    iq = torch.arange(m, device=Q.device)
    Sxx = P.new_zeros(B, n, m)
    Syy = P.new_zeros(B, n, m)
    Syx = P.new_zeros(B, n, m)
    Sxy = P.new_zeros(B, n, m)
    xb = P.new_zeros(B, n)
    yb = P.new_zeros(B, n)
    xq = P.new_zeros(B, m)
    yq = P.new_zeros(B, m)
    for o in offs:
        Po = P[:, (ip + o).clamp(0, n - 1)]                                    # (B, n, K, 3)
        Qo = Q[:, (iq + o).clamp(0, m - 1)]
        px, py = Po[..., 0], Po[..., 1]                                        # (B, n, K)
        qx, qy = Qo[..., 0], Qo[..., 1]
        Sxx += px @ qx.transpose(1, 2)
        Syy += py @ qy.transpose(1, 2)
        Syx += py @ qx.transpose(1, 2)
        Sxy += px @ qy.transpose(1, 2)
        xb += px.sum(-1)
        yb += py.sum(-1)
        xq += qx.sum(-1)
        yq += qy.sum(-1)
    N = float(K * len(offs))
    num = Syx - Sxy - (yb.unsqueeze(2) * xq.unsqueeze(1) - xb.unsqueeze(2) * yq.unsqueeze(1)) / N
    den = Sxx + Syy - (xb.unsqueeze(2) * xq.unsqueeze(1) + yb.unsqueeze(2) * yq.unsqueeze(1)) / N
    return torch.atan2(num, den)


def sign_cost(fp: torch.Tensor, fq: torch.Tensor) -> torch.Tensor:
    """Eq. 6 for signs in a common frame: ``cost[b, i, j] = sum_c (fp[b, i, c] - fq[b, j, c])^2``.

    Args:
        fp: body signs, (B, n, K, 6) int8 (or any real dtype)
        fq: hand signs, (B, m, K, 6)

    Returns:
        cost: (B, n, m), float32, integers in [0, 24 K]
    """
    a = fp.reshape(fp.shape[0], fp.shape[1], -1).float()
    b = fq.reshape(fq.shape[0], fq.shape[1], -1).float()
    return ((a * a).sum(-1).unsqueeze(2) + (b * b).sum(-1).unsqueeze(1) - 2.0 * (a @ b.transpose(1, 2))).round()


def sign_cost_yaw(vp: torch.Tensor, ap: torch.Tensor, vq: torch.Tensor, aq: torch.Tensor, theta: torch.Tensor, *,
                  dead_zone: float = 0.05, block: int = 64) -> torch.Tensor:
    """Eq. 6 literally: the hand's derivatives rotated by ``R_z(theta[i, j])`` per cell, then signs compared.

    Args:
        vp, ap: body velocity and acceleration, (B, n, K, 3)
        vq, aq: hand velocity and acceleration, (B, m, K, 3)
        theta: per-cell yaw from :func:`window_yaw`, (B, n, m), radians
        dead_zone: as in :func:`signs_from_derivatives` (thresholds from each clip's own magnitudes)
        block: rows per block (bounds memory at B * block * m * K * 4 values)

    Returns:
        cost: (B, n, m), float32, integers in [0, 24 K]
    """
    B, n, K, _ = vp.shape
    m = vq.shape[1]
    sp = signs_from_derivatives(vp, ap, dead_zone).float()                     # (B, n, K, 6)
    sq = signs_from_derivatives(vq, aq, dead_zone).float()                     # vertical signs need no rotation

    def thresholds(d: torch.Tensor) -> torch.Tensor:
        return dead_zone * torch.quantile(d[..., :2].norm(dim=-1), 0.95, dim=1)   # (B, K)

    th = [thresholds(vq), thresholds(aq)]
    out = vp.new_empty(B, n, m, dtype=torch.float32)
    zp = torch.cat([sp[..., 2:3], sp[..., 5:6]], -1).reshape(B, n, -1)          # vertical: (B, n, 2K)
    zq = torch.cat([sq[..., 2:3], sq[..., 5:6]], -1).reshape(B, m, -1)
    zcost = (zp * zp).sum(-1).unsqueeze(2) + (zq * zq).sum(-1).unsqueeze(1) - 2.0 * (zp @ zq.transpose(1, 2))
    hp = [sp[..., 0:2], sp[..., 3:5]]                                            # body horizontal signs (B, n, K, 2)
    hq = [vq[..., :2], aq[..., :2]]                                              # hand horizontal vectors (B, m, K, 2)
    for r0 in range(0, n, block):
        r1 = min(n, r0 + block)
        c = torch.cos(theta[:, r0:r1]).unsqueeze(-1).float()                    # (B, b, m, 1)
        s = torch.sin(theta[:, r0:r1]).unsqueeze(-1).float()
        acc = zcost[:, r0:r1].clone()
        for d in range(2):
            qx = hq[d][..., 0].unsqueeze(1).float()                              # (B, 1, m, K)
            qy = hq[d][..., 1].unsqueeze(1).float()
            t = th[d].view(B, 1, 1, K).float()
            rx = c * qx - s * qy                                                 # (B, b, m, K)
            ry = s * qx + c * qy
            sx = torch.sign(rx) * (rx.abs() > t)
            sy = torch.sign(ry) * (ry.abs() > t)
            px = hp[d][:, r0:r1, :, 0].unsqueeze(2)                              # (B, b, 1, K)
            py = hp[d][:, r0:r1, :, 1].unsqueeze(2)
            acc += ((px - sx) ** 2 + (py - sy) ** 2).sum(-1)
        out[:, r0:r1] = acc
    return out


def forearm_hand_vectors(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Eq. 8: forearm and hand vectors from the wrist midpoint, and the wrist axis p1 - p2.

    Args:
        x: markers (B, T, 4, 3) in the paper's order p1, p2 (wrist), p3 (forearm), p4 (hand)

    Returns:
        f: (B, T, 3) = p3 - (p1 + p2)/2; h: (B, T, 3) = p4 - (p1 + p2)/2; w: (B, T, 3) = p1 - p2
    """
    mid = 0.5 * (x[:, :, 0] + x[:, :, 1])
    return x[:, :, 2] - mid, x[:, :, 3] - mid, x[:, :, 0] - x[:, :, 1]


def palm_cost(hp: torch.Tensor, hq: torch.Tensor) -> torch.Tensor:
    """Eq. 9 with hand vectors already in a common frame: the angle between them.

    Args:
        hp: body hand vectors, (B, n, 3); hq: hand-clip hand vectors, (B, m, 3) (any non-zero lengths)

    Returns:
        cost: (B, n, m), radians in [0, pi]
    """
    a = hp / hp.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    b = hq / hq.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.acos((a @ b.transpose(1, 2)).clamp(-1.0, 1.0))


def _check_markers(x: torch.Tensor, name: str) -> None:
    if not isinstance(x, torch.Tensor) or x.dim() != 4 or x.shape[-1] != 3:
        shape = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
        raise ValueError(f"{name}: expected marker positions of shape (B, T, K, 3), got {shape}")
    if not x.is_floating_point():
        raise TypeError(f"{name}: expected a floating dtype, got {x.dtype}")
