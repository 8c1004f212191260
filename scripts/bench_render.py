"""Offscreen rendering rate: a 2-second clip of a built-in scene at 640x480, frames per second.

The scene's hand sits at its rest pose along the wrist track with the contacts and forces of the render tests'
fixture (cyan / yellow dots, red arrows), so the work per frame is what `torchhand render` does: pose the links, rebuild
the overlays, draw with shadows (and without, for comparison), read the pixels back, and draw the labels and legend.
Video encoding is not included. Reports the median and spread of several runs.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, os.path.dirname(__file__))
from _timing import machine, print_table, time_fn, write_json  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def bench_render(scene: str = "box-turn", seconds: float = 2.0, size=(640, 480), repeats: int = 5,
                 shadows=(True, False)) -> list[dict]:
    from tests.render.fixture_result import write_fixture_result
    from torchhand.render.backend import select_platform
    from torchhand.render.clip import clip_from_solution
    from torchhand.render.compose import RenderOptions, panel_camera, render_frames
    from torchhand.io.result import load_result

    import torchhand

    fps = torchhand.load_scene(scene).fps
    frames = int(round(seconds * fps))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = write_fixture_result(Path(tmp) / scene, scene, frames=frames, solutions=1)
        result = load_result(root)
        clip = clip_from_solution(result, result.solution(0), labels=["solution 0"])
        platform = select_platform()
        for sh in shadows:
            opts = RenderOptions(width=size[0], height=size[1], shadows=sh)
            camera = panel_camera([clip], opts, clip.T, clip.fps)

            def run():
                for _ in render_frames([clip], opts, camera=camera):
                    pass

            t = time_fn(run, "cpu", repeats=repeats, warmup=1)
            rows.append({"scene": scene, "size": f"{size[0]}x{size[1]}", "frames": frames, "shadows": sh,
                         "platform": platform, **t, "frames_per_s": frames / t["median_s"],
                         "fps_min": frames / t["max_s"], "fps_max": frames / t["min_s"]})
    return rows


def _gl_renderer() -> str:
    try:
        from OpenGL import GL

        return GL.glGetString(GL.GL_RENDERER).decode()
    except Exception:  # noqa: BLE001 - informational only
        return ""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--scene", default="box-turn")
    p.add_argument("--seconds", type=float, default=2.0)
    p.add_argument("--size", default="640x480")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json")
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.size.split("x"))
    rows = bench_render(a.scene, a.seconds, (w, h), a.repeats)
    print_table(rows, ["scene", "size", "frames", "shadows", "platform", "median_s", "iqr_s", "frames_per_s",
                       "fps_min", "fps_max"])
    info = machine()
    info["gl_renderer"] = _gl_renderer()
    print(f"GL renderer: {info['gl_renderer'] or 'unknown'}")
    if a.json:
        write_json(a.json, {"machine": info, "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
