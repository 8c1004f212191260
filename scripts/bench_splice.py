"""Splicing speed (Majkowska et al. 2006, Table 3: 569 frames in 10.95 s in Matlab).

Cases (median of --repeat runs, one torch thread unless --threads):
  align      the whole alignment (features, both passes, merge) of a 569-frame body with 569-, 1138- and
             2276-frame hands, and the paper's other lengths (503, 560, 280 frames with equal hands): the mocapbank
             body resampled to the length and a warped L4 session of it; modes: trunk (the default, the session
             has a trunk), handonly (the session seen as a hand capture: 12 yaws tried in one batched DTW), paper
  cost       Eq. 6 (trunk mode, one matrix product) and Eq. 6/7 (paper mode, per-cell yaw) alone, 569 x 2276
  splice     one full splice of clips (the CLI path less file I/O): the 569-frame body and its session carrying
             ManipNet's fingers
  batch      B pairs of 200 x 200 marker tracks: pass 1 aligned in one call; and the DTW alone on the Eq. 6
             costs vs dtaidistance's N-d DTW per pair on the same costs (Eq. 6 is the squared Euclidean distance
             of the 24 sign channels, which dtaidistance sums), 10 % band, pairs per second

    python scripts/bench_splice.py [--repeat 5] [--json out.json] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from torchhand.scene.bvh import read_bvh
from torchhand.kernels.dtw import dtw
from torchhand.kernels.splice_cost import sign_cost, sign_cost_yaw, sign_features, smooth_derivatives, window_yaw
from torchhand.splice.align import SpliceSettings, align, band_width
from torchhand.splice.markers import virtual_markers
from torchhand.splice.rigs import detect_rig
from torchhand.splice.splice import arm_joints, clip_axes

DATA = Path(os.environ.get("TORCHHAND_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data")) \
    / "mocap"
BODY = DATA / "bvh_python_tests" / "test_mocapbank.bvh"


def _sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def _time(fn, repeat: int, device: str) -> tuple[float, float]:
    fn()
    ts = []
    for _ in range(repeat):
        _sync(device)
        t0 = time.perf_counter()
        fn()
        _sync(device)
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts), (max(ts) - min(ts))


def _resample(x: torch.Tensor, T: int) -> torch.Tensor:
    src = torch.linspace(0, x.shape[0] - 1, T, dtype=torch.float64)
    i0 = src.floor().long().clamp(max=x.shape[0] - 2)
    w = (src - i0).view(-1, *([1] * (x.dim() - 1))).to(x.dtype)
    return x[i0] * (1 - w) + x[i0 + 1] * w


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    dev = args.device
    if not BODY.is_file():
        print(f"needs {BODY}", file=sys.stderr)
        return 1
    body = read_bvh(BODY)
    rig = detect_rig(body)
    units, up = clip_axes(body, rig, "right")
    mk = virtual_markers(body, arm_joints(body, rig, "right"), units_scale=units, up_axis=up)
    rows = []

    def add(case, n, m, mode, med, spread, ref=None):
        rows.append({"case": case, "n": n, "m": m, "mode": mode, "median_s": med, "spread_s": spread, "ref": ref})
        extra = f"  paper Matlab {ref:.2f} s -> {ref / med:.0f}x" if ref else ""
        print(f"{case:7s} {n:5d} x {m:5d} {mode:7s} {med * 1000:9.1f} ms  (spread {spread * 1000:.1f}){extra}",
              flush=True)

    paper = {569: 10.95, 503: 8.72, 560: 10.81, 280: 2.75}
    from torchhand.splice import splice
    from torchhand.splice.retime import retime_motion
    from torchhand.splice.synthetic import make_hand_session, with_fingers

    manip_path = DATA / "manipnet" / "mug1" / "rightHand.bvh"
    manip = read_bvh(manip_path) if manip_path.is_file() else None
    mrig = detect_rig(manip) if manip is not None else None
    arms = [rig.arms[s_] for s_ in ("right", "left")]
    aj = arm_joints(body, rig, "right")
    shapes = [(569, 569), (569, 1138), (569, 2276), (503, 503), (560, 560), (280, 280)]
    for n, m in shapes:
        # the mocapbank body resampled to n frames; an L4 session of it (warped, still trunk) with m frames
        bn = body.with_motion(retime_motion(body, np.linspace(0, body.num_frames - 1, n)))
        T_b = (n - 1) * body.frame_time
        hs = make_hand_session(bn, "L4", torch.Generator().manual_seed(0), shoulders=[a.shoulder for a in arms],
                               elbows=[a.elbow for a in arms], wrists=[a.wrist for a in arms], up_axis=up,
                               units_scale=units, hand_fps=(m - 1) / T_b)
        mb = virtual_markers(bn, aj, units_scale=units, up_axis=up)
        mh = virtual_markers(hs.clip, aj, units_scale=units, up_axis=up)
        mm = mh.num_frames
        P, S, R = mb.markers[None].to(dev), mb.shoulder[None].to(dev), mb.trunk[None].to(dev)
        Q, QS, QR = mh.markers[None].to(dev), mh.shoulder[None].to(dev), mh.trunk[None].to(dev)
        for mode, hand_trunk in (("trunk", True), ("handonly", False), ("paper", True)):
            st = SpliceSettings(features="paper" if mode == "paper" else "trunk")
            fn = lambda: align(P, Q, body_fps=mb.fps, hand_fps=mh.fps, body_shoulder=S, body_trunk=R,
                               hand_shoulder=QS if hand_trunk else None, hand_trunk=QR if hand_trunk else None,
                               settings=st)
            med, spread = _time(fn, args.repeat, dev)
            add("align", n, mm, mode, med, spread, paper.get(n) if n == m else None)
        if manip is not None and n == 569:
            # the whole splice of clips (rigs, markers, both passes, merge, resampling, retargeting; no file I/O):
            # the session carries ManipNet's fingers
            bt = hs.warp.inverse(np.arange(mm) / hs.clip.fps)
            hand, _ = with_fingers(hs.clip, rig, "right", manip, mrig, 600 + bt * manip.fps,
                                   finger_handedness="left", up_axis=up)
            med, spread = _time(lambda: splice(bn, hand), args.repeat, "cpu")
            add("splice", n, mm, "trunk", med, spread, paper[569] if mm == 569 else None)

    n, m = 569, 2276
    P = _resample(mk.markers, n)[None].to(dev)
    Q = _resample(mk.markers, m)[None].to(dev)
    fn = lambda: sign_cost(sign_features(P, 30.0), sign_features(Q, 120.0))
    add("cost", n, m, "trunk", *_time(fn, args.repeat, dev))

    def paper_cost():
        th = window_yaw(P, Q)
        vp, ap_ = smooth_derivatives(P, 30.0)
        vq, aq = smooth_derivatives(Q, 120.0)
        return sign_cost_yaw(vp, ap_, vq, aq, th)

    add("cost", n, m, "paper", *_time(paper_cost, args.repeat, dev))

    B, L = args.batch, 200
    g = torch.Generator().manual_seed(0)
    starts = torch.randint(0, mk.num_frames - L - 3, (B,), generator=g).tolist()
    PB = torch.stack([mk.markers[s:s + L] for s in starts]).to(dev)
    QB = torch.stack([mk.markers[s + 3:s + 3 + L] for s in starts]).to(dev)
    SB = torch.stack([mk.shoulder[s:s + L] for s in starts]).to(dev)
    RB = torch.stack([mk.trunk[s:s + L] for s in starts]).to(dev)
    QSB = torch.stack([mk.shoulder[s + 3:s + 3 + L] for s in starts]).to(dev)
    QRB = torch.stack([mk.trunk[s + 3:s + 3 + L] for s in starts]).to(dev)
    st = SpliceSettings(passes=1)
    med, spread = _time(lambda: align(PB, QB, body_fps=30.0, hand_fps=30.0, body_shoulder=SB, body_trunk=RB,
                                      hand_shoulder=QSB, hand_trunk=QRB, settings=st), args.repeat, dev)
    add("batch", L, L, f"align B={B}", med, spread)
    rows[-1]["pairs_per_s"] = B / med
    # the DP alone on Eq. 6 costs vs dtaidistance on the same costs: Eq. 6 is the squared Euclidean distance of
    # the 24 sign channels, which is what dtaidistance's N-d DTW sums (it returns the square root of the sum)
    W, r = band_width(0.10, L, L)
    fp, fq = sign_features(PB, 30.0), sign_features(QB, 30.0)
    C = sign_cost(fp, fq).double()
    med, spread = _time(lambda: dtw(C, band=W), args.repeat, dev)
    add("batch", L, L, f"dtw B={B}", med, spread)
    rows[-1]["pairs_per_s"] = B / med
    try:
        from dtaidistance import dtw_ndim
    except ImportError:
        print("dtaidistance not installed: no reference row", file=sys.stderr)
    else:
        xs = [np.ascontiguousarray(fp[b].reshape(L, -1).double().cpu().numpy()) for b in range(B)]
        ys = [np.ascontiguousarray(fq[b].reshape(L, -1).double().cpu().numpy()) for b in range(B)]
        win = int(np.floor(W * np.sqrt(2.0) + 1e-9)) + 1       # dtaidistance: |i - j| < window
        ref = [dtw_ndim.distance_fast(x, y, window=win) ** 2 for x, y in zip(xs, ys)]
        ours = dtw(C, band=W).distance.cpu().numpy()
        agree = float(np.max(np.abs(np.array(ref) - ours) / np.maximum(1.0, np.abs(ours))))
        ref_med, ref_spread = _time(lambda: [dtw_ndim.distance_fast(x, y, window=win) for x, y in zip(xs, ys)],
                                    args.repeat, "cpu")
        rows.append({"case": "batch", "n": L, "m": L, "mode": f"dtaidistance B={B}", "median_s": ref_med,
                     "spread_s": ref_spread, "pairs_per_s": B / ref_med, "max_rel_diff": agree})
        print(f"batch   {L} x {L}, 10 % band, same Eq. 6 costs: torchhand dtw {B / med:8.0f} pairs/s, dtaidistance "
              f"{B / ref_med:8.0f} pairs/s (ratio {ref_med / med:.2f}); distances agree to {agree:.1e}")
    if args.json:
        Path(args.json).write_text(json.dumps({"device": dev, "threads": args.threads, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
