"""FK + point-Jacobian throughput of torchhand against pytorch_kinematics on the same hand.

The reference parses the hand's exported MJCF. pytorch_kinematics allows one joint per body, so bodies with 2- and
3-DOF joints are split into nested bodies at the same frame (identical kinematics), and the root's free joint is
dropped (both sides use the identity root). Work per call on both sides: poses of all links plus the Jacobian of the
five fingertip points.
"""

from __future__ import annotations

import argparse
import sys
import xml.etree.ElementTree as ET

import torch

sys.path.insert(0, __import__("os").path.dirname(__file__))
from _timing import machine, print_table, time_fn, write_json  # noqa: E402

import torchhand  # noqa: E402


def pk_compatible_mjcf(xml: str) -> str:
    """Split multi-joint bodies into nested single-joint bodies and drop the root's free joint."""
    root = ET.fromstring(xml)
    for parent in root.iter():
        for fj in [c for c in parent if c.tag == "freejoint" or (c.tag == "joint" and c.get("type") == "free")]:
            parent.remove(fj)
    for body in list(root.iter("body")):
        joints = [c for c in body if c.tag == "joint"]
        if len(joints) <= 1:
            continue
        rest = [c for c in body if c.tag != "joint"]
        for c in list(body):
            if c.tag != "inertial":
                body.remove(c)
        body.append(joints[0])
        name = body.get("name")
        body.set("name", f"{name}__j0")
        outer = body
        for k, j in enumerate(joints[1:], start=1):
            inner = ET.SubElement(outer, "body", {"name": name if k == len(joints) - 1 else f"{name}__j{k}"})
            ET.SubElement(inner, "inertial", {"pos": "0 0 0", "mass": "0.001", "diaginertia": "1e-7 1e-7 1e-7"})
            inner.append(j)
            outer = inner
        for c in rest:
            if c.tag != "inertial":
                outer.append(c)
    return ET.tostring(root, encoding="unicode")


def _tip_inputs(hand):
    return hand.distal_link, hand.fingertip


def bench_fk(device: str = "cpu", dtype: torch.dtype = torch.float32, batch_sizes=(1, 64, 4096, 65536),
             repeats: int = 7, reference: bool = True) -> list[dict]:
    hand = torchhand.default_hand().to(device=device, dtype=dtype)
    gen = torch.Generator().manual_seed(0)
    links, tips = _tip_inputs(hand)
    rows = []
    chain_pk = serial = None
    if reference:
        import pytorch_kinematics as pk

        xml = pk_compatible_mjcf(hand.to_mjcf())
        chain_pk = pk.build_chain_from_mjcf(xml).to(dtype=dtype, device=device)
        pk_names = chain_pk.get_joint_parameter_names()
        perm = torch.tensor([hand.joint_index(n) for n in pk_names], device=device)
        serial = []
        for f in range(hand.num_fingers):
            name = hand.link_names[int(links[f])]
            sc = pk.SerialChain(chain_pk, name).to(dtype=dtype, device=device)
            cols = torch.tensor([hand.joint_index(n) for n in sc.get_joint_parameter_names()], device=device)
            serial.append((sc, cols, tips[f].reshape(1, 3)))
    for B in batch_sizes:
        q = hand.random_q(B, gen).to(device)

        def ours():
            return hand.kinematics(q, links, tips)  # link poses, tip positions, tip Jacobians

        t = time_fn(ours, device, repeats=repeats, min_time=0.05)
        rows.append({"name": "torchhand fk+jac", "device": device, "dtype": str(dtype).replace("torch.", ""),
                     "B": B, **t, "per_s": B / t["median_s"]})
        if reference:
            qpk = q[:, perm]

            def theirs():
                T = chain_pk.forward_kinematics(qpk)
                Js = [sc.jacobian(q[:, cols], locations=loc.expand(B, 3)) for sc, cols, loc in serial]
                return T, Js

            tr = time_fn(theirs, device, repeats=max(3, repeats // 2), min_time=0.05)
            rows.append({"name": "pytorch_kinematics fk+jac", "device": device,
                         "dtype": str(dtype).replace("torch.", ""), "B": B, **tr, "per_s": B / tr["median_s"],
                         "ratio": tr["median_s"] / t["median_s"]})
    return rows


def check_against_reference(dtype=torch.float64) -> float:
    """Max |position| difference between torchhand and pytorch_kinematics over all links (a sanity check)."""
    import pytorch_kinematics as pk

    hand = torchhand.default_hand().to(dtype=dtype)
    chain_pk = pk.build_chain_from_mjcf(pk_compatible_mjcf(hand.to_mjcf())).to(dtype=dtype)
    q = hand.random_q(16, torch.Generator().manual_seed(1))
    perm = [hand.joint_index(n) for n in chain_pk.get_joint_parameter_names()]
    ref = chain_pk.forward_kinematics(q[:, perm])
    T = hand.forward_kinematics(q)
    err = 0.0
    for i, name in enumerate(hand.link_names):
        m = ref[name].get_matrix()
        err = max(err, float((m - T[:, i]).abs().max()))
    return err


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--device", default="cpu")
    p.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    p.add_argument("--batch", type=int, nargs="+", default=[1, 64, 4096, 65536])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--json")
    a = p.parse_args(argv)
    print(f"pytorch_kinematics agreement (float64, max abs over link poses): {check_against_reference():.2e}")
    rows = bench_fk(a.device, getattr(torch, a.dtype), a.batch, a.repeats)
    print_table(rows, ["name", "device", "dtype", "B", "median_s", "iqr_s", "per_s", "ratio"])
    if a.json:
        write_json(a.json, {"machine": machine(), "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
