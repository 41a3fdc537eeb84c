"""BVH inputs (issue 17, readers): parsed and posed by bvhio, matched onto the Human3.6M skeleton by joint
name, then forecast and repaired as h36m32 poses in world coordinates."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("bvhio")

from tcd import _bvh as bvh, wild  # noqa: E402
from tcd._cli import main  # noqa: E402

# a small CMU-style hierarchy in centimetres: (name, parent, offset)
JOINTS = [
    ("Hips", None, (0, 0, 0)),
    ("LeftUpLeg", "Hips", (10, 0, 0)),
    ("LeftLeg", "LeftUpLeg", (0, -45, 0)),
    ("LeftFoot", "LeftLeg", (0, -45, 0)),
    ("LeftToeBase", "LeftFoot", (0, -5, 12)),
    ("RightUpLeg", "Hips", (-10, 0, 0)),
    ("RightLeg", "RightUpLeg", (0, -45, 0)),
    ("RightFoot", "RightLeg", (0, -45, 0)),
    ("RightToeBase", "RightFoot", (0, -5, 12)),
    ("Spine", "Hips", (0, 10, 0)),
    ("Spine1", "Spine", (0, 25, 0)),
    ("Neck", "Spine1", (0, 25, 0)),
    ("Head", "Neck", (0, 12, 0)),
    ("LeftShoulder", "Spine1", (5, 20, 0)),
    ("LeftArm", "LeftShoulder", (12, 0, 0)),
    ("LeftForeArm", "LeftArm", (28, 0, 0)),
    ("LeftHand", "LeftForeArm", (25, 0, 0)),
    ("RightShoulder", "Spine1", (-5, 20, 0)),
    ("RightArm", "RightShoulder", (-12, 0, 0)),
    ("RightForeArm", "RightArm", (-28, 0, 0)),
    ("RightHand", "RightForeArm", (-25, 0, 0)),
]
FRAMES, FPS = 75, 30.0


def write_bvh(path):
    """A walk along +z at 0.9 m/s (3 cm per frame), the hips 95 cm up, no joint rotation; arms swing about x."""
    children = {n: [c for c, p, _ in JOINTS if p == n] for n, _, _ in JOINTS}
    offsets = {n: o for n, _, o in JOINTS}
    lines, order = ["HIERARCHY"], []

    def emit(name, depth):
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {name}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {' '.join(str(float(v)) for v in offsets[name])}")
        channels = (
            "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
            if depth == 0
            else "3 Zrotation Xrotation Yrotation"
        )
        lines.append(f"{pad}  CHANNELS {channels}")
        order.append(name)
        for c in children[name]:
            emit(c, depth + 1)
        if not children[name]:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0.0 5.0 0.0", pad + "  }"])
        lines.append(pad + "}")

    emit("Hips", 0)
    lines += ["MOTION", f"Frames: {FRAMES}", f"Frame Time: {1 / FPS:.8f}"]
    for f in range(FRAMES):
        row = [0.0, 95.0, 3.0 * f, 0.0, 0.0, 0.0]
        for name in order[1:]:
            swing = 20.0 * np.sin(f / 5.0) if name in ("LeftArm", "RightArm") else 0.0
            row += [0.0, swing, 0.0]
        lines.append(" ".join(f"{v:.4f}" for v in row))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_read_bvh_and_match_names(tmp_path):
    pos, names, parents, fps = bvh.read_bvh(write_bvh(tmp_path / "walk.bvh"))
    assert pos.shape == (FRAMES, len(JOINTS), 3) and fps == pytest.approx(FPS)
    assert names == [n for n, _, _ in JOINTS] or set(names) == {n for n, _, _ in JOINTS}
    hips = names.index("Hips")
    np.testing.assert_allclose(
        pos[:, hips], np.stack([np.zeros(FRAMES), np.full(FRAMES, 95.0), 3.0 * np.arange(FRAMES)], 1), atol=1e-4
    )
    x32 = bvh.to_h36m32(pos, names, parents)
    for id32, name in {
        0: "Hips",
        1: "RightUpLeg",
        6: "LeftUpLeg",
        11: "Spine",
        12: "Spine1",
        13: "Neck",
        14: "Head",
        17: "LeftArm",
        19: "LeftHand",
        27: "RightHand",
    }.items():
        np.testing.assert_array_equal(x32[:, id32], pos[:, names.index(name)])
    assert np.isnan(x32[:, [5, 10, 15, 21, 22, 29, 30]]).all()  # no toe sites, head site, thumbs, fingers


def test_forecast_and_repair_a_bvh_file(tiny_model_dir, tmp_path, capsys):
    (tmp_path / "in").mkdir()
    src = write_bvh(tmp_path / "in" / "walk.bvh")
    out = tmp_path / "f.npz"
    assert (
        main(
            [
                "forecast",
                str(src),
                "-o",
                str(out),
                "--model",
                str(tiny_model_dir),
                "--units",
                "cm",
                "--samples",
                "1",
                "--steps",
                "2",
                "--sampler",
                "ddim",
            ]
        )
        == 0
    )
    with np.load(out) as z:
        assert z["mean"].shape == (30, 32, 3) and z["repaired"].shape == (FRAMES, 32, 3)  # 1 s at 30 fps
        np.testing.assert_allclose(z["times"], np.arange(1, 31) / FPS, atol=1e-6)
        # the root walks on along +z from 3 cm per frame (0.9 m/s: 3.6 cm per 25 fps model frame), its speed
        # less tcd.wild.ROOT_DEAD_ZONE_MPS, slowing with the time constant of tcd.wild.ROOT_DAMPING_S; read at
        # the file's 30 fps from the model frames
        tau = wild.ROOT_DAMPING_S * 25.0
        model_frames = np.arange(26)
        kept = (0.9 - wild.ROOT_DEAD_ZONE_MPS) / 0.9
        travel = 3.6 * kept * tau * (1 - np.exp(-model_frames / tau))
        want = 3.0 * (FRAMES - 1) + np.interp(np.arange(1, 31) * 25.0 / FPS, model_frames, travel)
        np.testing.assert_allclose(z["mean"][:, 0, 2], want, atol=1e-6)
    assert (
        main(
            [
                "repair",
                str(tmp_path / "in"),
                "-o",
                str(tmp_path / "rep"),
                "--model",
                str(tiny_model_dir),
                "--units",
                "cm",
                "--samples",
                "1",
                "--steps",
                "2",
                "--sampler",
                "ddim",
                "--quiet",
            ]
        )
        == 0
    )
    pos, names, parents, _ = bvh.read_bvh(src)
    x32 = bvh.to_h36m32(pos, names, parents)
    with np.load(tmp_path / "rep" / "walk.npz") as z:
        seen = ~np.isnan(x32)
        assert z["poses"].shape == (FRAMES, 32, 3) and np.array_equal(z["poses"][seen], x32[seen])
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nnot a bvh\n")
    assert main(["forecast", str(bad), "-o", str(tmp_path / "x.npz"), "--model", str(tiny_model_dir)]) == 2
    assert "not a readable BVH file" in capsys.readouterr().err
