"""Poses from the wild (issue 17, first part): the joint layouts' mappings, world coordinates, frame rates
and lengths, through the public API (tcd.TCD.forecast / repair with capture=tcd.Capture(layout, fps, up))."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures_util import bad
from tcd import layouts, wild
from tcd._demo import load_clip
from tcd import Capture, SamplerOptions

FAST = dict(num_samples=2, seed=0, sampler=SamplerOptions(sampler="ddim", num_inference_steps=3))
SAME_PLACE = {16: 13, 20: 19, 23: 22, 24: 13, 28: 27, 31: 30}


def h36m32(frames: int = 50) -> np.ndarray:
    """The demo clip (model layout, on the Human3.6M skeleton) as 32-joint Human3.6M poses."""
    clip = load_clip()["poses"].astype(np.float64)[:frames]
    rest, _ = wild._rest()
    x = np.zeros((len(clip), 32, 3))
    x[:, list(layouts.MODEL_IDS)] = clip
    x[:, list(layouts.FIXED_IDS)] = rest[list(layouts.FIXED_IDS)]
    for dst, src in SAME_PLACE.items():
        x[:, dst] = x[:, src]
    return x


def world(x: np.ndarray, angle: float = 0.7, shift=(10.0, -3.0, 0.9)) -> np.ndarray:
    """Canonical poses (+y up) turned by ``angle`` about a z-up world's vertical and moved by ``shift``."""
    return np.einsum("ij,tkj->tki", _world_rot(angle), x) + np.asarray(shift)


def _world_rot(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])


def in_layout(x32: np.ndarray, name: str) -> np.ndarray:
    """32-joint poses as the given layout would hold them (face points and spine joints made up plausibly)."""
    lay = layouts.get_layout(name)
    out = np.full((len(x32), lay.num_joints, 3), np.nan)
    for i, t in enumerate(lay.to32):
        if t is not None:
            out[:, i] = x32[:, t]
    if name == "coco17":
        side = x32[:, 6] - x32[:, 1]
        out[:, 3], out[:, 4] = x32[:, 14] + 0.3 * side, x32[:, 14] - 0.3 * side  # ears
        out[:, 0] = out[:, 1] = out[:, 2] = x32[:, 15]  # nose, eyes
    if name == "smpl24":
        out[:, 3], out[:, 6], out[:, 13], out[:, 14] = x32[:, 11], x32[:, 12], x32[:, 16], x32[:, 24]
    return out


@pytest.mark.parametrize("name", ["h36m32", "h36m17", "smpl24", "coco17"])
def test_layout_round_trip_is_exact(name):
    """Into the model's convention and back on the same frames: every joint the caller gave comes back."""
    x = in_layout(world(h36m32()), name)
    y, scene = wild.to_model(x[None], layouts.get_layout(name), wild.up_vector("z"))
    back = wild.from_model(y, scene, scene.root, scene.rot, own_frames=True)[0]
    np.testing.assert_allclose(back, x, rtol=0, atol=1e-12)
    # of the model joints the layout lacks, the ends (hands, toes, sites: h36m17's 8, smpl24's 5, coco17's 5) are
    # carried on their parents' bones; the rest (coco17's thorax, between the shoulders and the spine) in-painted
    lacks = {"h36m32": 0, "h36m17": 0, "smpl24": 0, "coco17": 1}[name]
    assert int(np.isnan(y[0, 0, :, 0]).sum()) == lacks


def test_h36m32_on_the_model_skeleton_costs_nothing(tiny_model):
    """h36m32 poses built on the Human3.6M skeleton, canonical: the native path's forecast, joined to the last
    observed pose over the first tcd.wild.JOIN_FRAMES frames (frame f: the last pose + f / 5 of the way to
    the native forecast), the native forecast itself after them."""
    x = h36m32()
    model = list(layouts.MODEL_IDS)
    native = tiny_model.forecast(x[:, model], **FAST)
    f = tiny_model.forecast(x, capture=Capture("h36m32"), **FAST)
    n = wild.JOIN_FRAMES
    assert n == 5
    w = np.minimum(np.arange(1, 26) / n, 1.0)[:, None, None]
    np.testing.assert_allclose(
        f.samples[:, :, model], x[-1, model] + (native.samples - x[-1, model]) * w, rtol=1e-5, atol=1e-6
    )
    np.testing.assert_allclose(f.samples[:, n - 1 :, model], native.samples[:, n - 1 :], rtol=1e-5, atol=1e-6)
    assert np.abs(native.samples[:, 0] - x[-1, model]).max() > 0.01  # the join has something to do
    np.testing.assert_allclose(f.times, native.times)
    assert f.mean.shape == (25, 32, 3)


@pytest.mark.parametrize("name", ["h36m32", "h36m17", "smpl24", "coco17"])
def test_world_coordinates_move_with_the_input(tiny_model, name):
    """Turning and moving the observation turns and moves the forecast and the repair with it."""
    a = in_layout(world(h36m32(), angle=0.2, shift=(0.0, 0.0, 0.0)), name)
    b = in_layout(world(h36m32(), angle=2.1, shift=(5.0, 7.0, -1.0)), name)
    fa = tiny_model.forecast(a, capture=Capture(name, up="z"), **FAST)
    fb = tiny_model.forecast(b, capture=Capture(name, up="z"), **FAST)
    turn = _world_rot(2.1) @ _world_rot(0.2).T
    np.testing.assert_allclose(np.einsum("ij,...j->...i", turn, fa.mean) + [5.0, 7.0, -1.0], fb.mean, atol=1e-9)
    gappy = b.copy()
    gappy[10:20, 3:6] = np.nan
    r = tiny_model.repair(gappy, capture=Capture(name, up="z"), **FAST).poses
    seen = ~np.isnan(gappy)
    assert np.array_equal(r[seen], gappy[seen]) and np.isfinite(r[10:20, 3:6]).all()


def test_any_frame_rate_and_length(tiny_model):
    x25 = h36m32()
    from tcd._resample import resample_backward

    x50 = resample_backward(x25.reshape(50, -1), 99, 50.0, 25.0).reshape(99, 32, 3)  # the same motion at 50 fps
    f25 = tiny_model.forecast(x25, capture=Capture("h36m32"), **FAST)
    f50 = tiny_model.forecast(x50, capture=Capture("h36m32", fps=50), **FAST)
    assert f50.mean.shape == (50, 32, 3)
    np.testing.assert_allclose(f50.times, np.arange(1, 51) / 50)
    np.testing.assert_allclose(f50.mean[1::2], f25.mean, atol=1e-6)  # every other 50 fps frame is a model frame
    short = tiny_model.forecast(x25[-20:], capture=Capture("h36m32"), **FAST)  # 0.8 s: padded with missing frames
    assert short.mean.shape == (25, 32, 3) and short.repaired.shape == (20, 32, 3) and np.isfinite(short.mean).all()
    long = tiny_model.forecast(
        np.concatenate([x25, x25]), capture=Capture("h36m32"), **FAST
    )  # 4 s: the last 2 s are used
    np.testing.assert_allclose(long.mean, f25.mean, atol=1e-9)
    bad("obs", tiny_model.repair, np.concatenate([x25, x25]), capture=Capture("h36m32"))  # repair: one window at most
    gone = np.concatenate([x25, np.full_like(x25, np.nan)])  # the last 2 s missing: the window is empty
    bad("obs", tiny_model.forecast, gone, capture=Capture("h36m32"))  # (here: no hips in it to place the body)
    e = bad("obs", tiny_model.forecast, gone[:, list(layouts.MODEL_IDS)], capture=Capture("h36m22"))
    assert "last 50 frames" in str(e)  # the rule without layout / fps


@pytest.mark.parametrize("damping_s", [None, 0.4, 0.0])
def test_the_future_root_continues_its_velocity_and_turn_rate(tiny_model, damping_s, monkeypatch):
    """The root's velocity and turn rate of the last 0.2 s, held (None) or decaying with time constant
    ``damping_s`` (the default, tcd.wild.ROOT_DAMPING_S), or the root held (0): future frame f is ``travel(f)``
    frames of the last velocity, its speed less the dead zone (tcd.wild.ROOT_DEAD_ZONE_MPS, here 0.2 m/s: 1.05 of
    this walker's 1.25 m/s), away, ``f`` or ``tau (1 - exp(-f / tau))``."""
    from tcd import wild

    monkeypatch.setattr(wild, "ROOT_DAMPING_S", damping_s)
    monkeypatch.setattr(wild, "ROOT_DEAD_ZONE_MPS", 0.2)
    f = np.arange(1, 26, dtype=np.float64)
    tau = None if damping_s is None else damping_s * 25.0
    travel = f if tau is None else (np.zeros_like(f) if tau == 0 else tau * (1 - np.exp(-f / tau)))
    x = h36m32()
    t = np.arange(50)[:, None, None]
    walking = x + t * np.array([0.0, 0.0, 0.05])  # 0.05 m per frame forward (1.25 m/s)
    out = tiny_model.forecast(walking, capture=Capture("h36m32"), **FAST)
    np.testing.assert_allclose(
        out.mean[:, 0], (49 * 0.05 + travel * 0.05 * 1.05 / 1.25)[:, None] * [0.0, 0.0, 1.0], atol=1e-9
    )
    rate = 0.02  # radians per frame about +y
    turning = np.stack([world_y(x[i], rate * i) for i in range(50)])
    out = tiny_model.forecast(turning, capture=Capture("h36m32"), **FAST)
    across = out.mean[:, 6] - out.mean[:, 1]  # right hip -> left hip
    heading = np.unwrap(np.arctan2(-across[:, 2], across[:, 0]))
    np.testing.assert_allclose(heading, rate * (49 + travel), atol=1e-9)


def world_y(pose: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return pose @ np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])


def test_bad_wild_inputs(tiny_model):
    x = h36m32()
    bad("layout", Capture, "openpose25")  # a capture checks its fields when it is made
    bad("obs", tiny_model.forecast, x[:, :17], capture=Capture("h36m32"))  # 17 joints are not h36m32's 32
    for fps in (0, -25, float("nan"), True, "25"):
        bad("fps", Capture, "h36m32", fps=fps)
    for up in ("w", (1.0, 1.0, 0.0), (0.0, 1.0)):
        bad("up", Capture, "h36m32", up=up)
    one = np.full_like(x, np.nan)
    one[7] = x[7]
    bad("obs", tiny_model.forecast, one, capture=Capture("h36m32"))  # one observed frame: no motion
    no_hips = x.copy()
    no_hips[:, [1, 6]] = np.nan
    bad("obs", tiny_model.forecast, no_hips, capture=Capture("h36m32"))  # nothing to place the body by


@pytest.mark.parametrize(
    "field,kwargs",
    [
        ("layout", {"layout": "openpose25"}),
        ("layout", {"layout": None}),
        ("layout", {"layout": 32}),
        ("fps", {"layout": "coco17", "fps": 0}),
        ("fps", {"layout": "coco17", "fps": -25.0}),
        ("fps", {"layout": "coco17", "fps": float("inf")}),
        ("fps", {"layout": "coco17", "fps": float("nan")}),
        ("fps", {"layout": "coco17", "fps": True}),
        ("fps", {"layout": "coco17", "fps": "25"}),
        ("up", {"layout": "coco17", "up": "w"}),
        ("up", {"layout": "coco17", "up": None}),
        ("up", {"layout": "coco17", "up": (1.0, 1.0, 0.0)}),
        ("up", {"layout": "coco17", "up": (0.0, 1.0)}),
        ("up", {"layout": "coco17", "up": (0.0, 0.0, 0.0)}),
    ],
)
def test_a_bad_capture_is_an_error_naming_the_field(field, kwargs):
    """tcd.Capture checks each field when it is made (no model needed): an InvalidInputError naming it."""
    bad(field, Capture, **kwargs)


def test_a_capture_is_frozen_and_normalised():
    c = Capture("coco17", fps=30, up="z")
    assert (c.layout, c.fps, c.up) == ("coco17", 30.0, "z") and isinstance(c.fps, float)
    assert Capture("h36m32") == Capture("h36m32", fps=None, up="y")
    v = Capture("coco17", up=np.array([0.0, 0.0, 1.0]))  # a vector: kept hashable
    assert v.up == (0.0, 0.0, 1.0) and hash(v) == hash(Capture("coco17", up=[0.0, 0.0, 1.0]))
    with pytest.raises(AttributeError):
        c.fps = 25.0  # type: ignore[misc]


def test_a_capture_is_a_capture_object(tiny_model):
    """The layout alone, a dict or the old keywords are refused: ``capture`` names a tcd.Capture (TCD.predict:
    tests/test_predict.py)."""
    x = h36m32()
    for call in (tiny_model.forecast, tiny_model.repair):
        bad("capture", call, x, capture="coco17", **FAST)
        bad("capture", call, x, capture={"layout": "h36m32"}, **FAST)
        for old in ({"layout": "h36m32"}, {"fps": 50}, {"up": "z"}):
            with pytest.raises(TypeError, match=next(iter(old))):
                call(x, **old, **FAST)


def test_a_capture_with_its_defaults_is_the_h36m22_wild_path(tiny_model):
    """``Capture("h36m22", fps=...)`` (the old ``layout=None, fps=...``) resamples the model's own joints: at the
    model's rate, the same forecast as ``Capture("h36m22")``; at twice the rate, twice the frames."""
    x = h36m32()[:, list(layouts.MODEL_IDS)]
    a = tiny_model.forecast(x, capture=Capture("h36m22", fps=25), **FAST)
    b = tiny_model.forecast(x, capture=Capture("h36m22"), **FAST)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert a.mean.shape == (25, 22, 3)
    from tcd._resample import resample_backward

    x50 = resample_backward(x.reshape(50, -1), 99, 50.0, 25.0).reshape(99, 22, 3)
    f50 = tiny_model.forecast(x50, capture=Capture("h36m22", fps=50), **FAST)
    assert f50.mean.shape == (50, 22, 3)
    np.testing.assert_allclose(f50.times, np.arange(1, 51) / 50)


def test_cli_forecast_with_layout_fps_and_up(tiny_model_dir, tmp_path, capsys):
    from tcd._cli import main

    x = in_layout(world(h36m32()), "h36m17")
    np.savez(tmp_path / "in.npz", poses=x * 1000)  # millimetres, z up, 25 fps
    out = tmp_path / "out.npz"
    assert (
        main(
            [
                "forecast",
                str(tmp_path / "in.npz"),
                "-o",
                str(out),
                "--model",
                str(tiny_model_dir),
                "--layout",
                "h36m17",
                "--fps",
                "25",
                "--up",
                "z",
                "--units",
                "mm",
                "--samples",
                "2",
                "--seed",
                "0",
                "--sampler",
                "ddim",
                "--steps",
                "3",
            ]
        )
        == 0
    )
    want = tcd_load(tiny_model_dir).forecast(x * 1000, capture=Capture("h36m17", fps=25, up="z"), units="mm", **FAST)
    with np.load(out) as z:
        np.testing.assert_array_equal(z["mean"], want.mean)
        np.testing.assert_array_equal(z["times"], want.times)
    assert (
        main(
            [
                "forecast",
                str(tmp_path / "in.npz"),
                "-o",
                str(tmp_path / "o2.npz"),
                "--model",
                str(tiny_model_dir),
                "--layout",
                "h36m17",
                "--fps",
                "0",
                "--units",
                "mm",
            ]
        )
        == 2
    )
    assert "(`fps` is --fps.)" in capsys.readouterr().err


def tcd_load(d):
    import tcd

    return tcd.load(d)


def test_repair_file_and_tcd_repair_with_a_layout(tiny_model_dir, tmp_path, capsys):
    """A long world-coordinate h36m17 file at 50 fps, repaired through the windows and back: observed values
    bit for bit, gaps filled, the provenance records the layout; tcd repair gives the same file."""
    from tcd._resample import resample_backward
    from tcd._cli import main

    x = in_layout(world(h36m32(75)), "h36m17")
    x50 = resample_backward(x.reshape(75, -1), 149, 50.0, 25.0).reshape(149, 17, 3)
    x50[40:60, 11:14] = np.nan  # the left arm lost for 0.4 s
    np.savez(tmp_path / "take.npz", poses=x50 * 1000)
    kw = dict(num_samples=1, sampler=SamplerOptions(num_inference_steps=2, sampler="ddim"))
    tcd_repair_file = __import__("tcd").repair_file
    tcd_repair_file(
        tmp_path / "take.npz",
        tmp_path / "api.npz",
        tiny_model_dir,
        capture=Capture("h36m17", fps=50, up="z"),
        units="mm",
        **kw,
    )
    with np.load(tmp_path / "api.npz") as z:
        out, prov = z["poses"], z["provenance"]
    seen = ~np.isnan(x50)
    assert out.shape == x50.shape and np.array_equal(out[seen], (x50 * 1000)[seen]) and np.isfinite(out).all()
    assert '"layout": "h36m17"' in str(prov) and '"up": "z"' in str(prov)
    assert (
        main(
            [
                "repair",
                str(tmp_path / "take.npz"),
                "-o",
                str(tmp_path / "cli"),
                "--model",
                str(tiny_model_dir),
                "--fps",
                "50",
                "--units",
                "mm",
                "--layout",
                "h36m17",
                "--up",
                "z",
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
    with np.load(tmp_path / "cli" / "take.npz") as z:
        np.testing.assert_array_equal(z["poses"], out)


# ---------------------------------------------------------------------------------------------- issue 27
SOMOF13 = (1, 2, 4, 5, 7, 8, 12, 16, 17, 18, 19, 20, 21)  # 3DPW through SoMoF: hips, knees, ankles, neck, arms


def test_a_13_joint_smpl_observation_without_a_pelvis_forecasts(tiny_model):
    """3DPW's 13 SoMoF joints as smpl24, no pelvis (issue 27, part 3): the root is the mid-point of the hips
    (where the model's skeleton has its pelvis), so on the Human3.6M skeleton the forecast is the one with
    the pelvis given; the pelvis the caller never gave is not made up (NaN in the forecast and the repair)."""
    full = in_layout(world(h36m32()), "smpl24")
    given = np.full_like(full, np.nan)
    given[:, list(SOMOF13)] = full[:, list(SOMOF13)]
    with_pelvis = given.copy()
    with_pelvis[:, 0] = full[:, 0]
    f = tiny_model.forecast(given, capture=Capture("smpl24", fps=25, up="z"), **FAST)
    want = tiny_model.forecast(with_pelvis, capture=Capture("smpl24", fps=25, up="z"), **FAST)
    assert f.mean.shape == (25, 24, 3) and np.isfinite(f.mean[:, list(SOMOF13)]).all()
    np.testing.assert_allclose(f.mean[:, list(SOMOF13)], want.mean[:, list(SOMOF13)], atol=1e-5)
    assert np.isnan(f.mean[:, 0]).all() and np.isnan(f.samples[..., 0, :]).all() and np.isnan(f.repaired[:, 0]).all()
    assert np.isfinite(want.mean[:, 0]).all()
    coco = in_layout(world(h36m32()), "coco17")  # COCO: hips only, as before
    assert np.isfinite(tiny_model.forecast(coco, capture=Capture("coco17", up="z"), **FAST).mean).all()


@pytest.mark.parametrize("name", ["h36m32", "smpl24"])
def test_a_pelvis_missing_in_some_frames_is_placed_by_the_hips(tiny_model, name):
    """Where the pelvis is missing, the root is the mid-point of the hips moved by the pelvis's own offset from
    it (measured in the root frame on the frames that show both): a pelvis 5 cm above its hips, as SMPL's,
    hidden for the last 0.8 s, is repaired to within the body frame's smoothing (tcd.wild.BODY_FRAME_SIGMA: under
    10 um on this turning walk; exactly without it) and forecasts as if it had been seen."""
    x = h36m32()
    x[:, 0] += [0.0, 0.05, 0.01]  # up and forward of the hips' mid-point
    x = np.stack([world_y(pose, 0.01 * i) for i, pose in enumerate(x)])  # turning while walking
    x += np.arange(50)[:, None, None] * [0.01, 0.0, 0.03]
    seen = in_layout(world(x), name)
    hidden = seen.copy()
    hidden[30:, 0] = np.nan
    r = tiny_model.repair(hidden, capture=Capture(name, up="z"), **FAST).poses
    np.testing.assert_allclose(r[30:, 0], seen[30:, 0], atol=1e-5)
    a = tiny_model.forecast(hidden, capture=Capture(name, up="z"), **FAST)
    b = tiny_model.forecast(seen, capture=Capture(name, up="z"), **FAST)
    np.testing.assert_allclose(a.mean, b.mean, atol=1e-5)


@pytest.mark.parametrize("name", ["h36m32", "h36m17", "smpl24", "coco17"])
def test_the_forecast_starts_at_the_last_observed_pose(name, monkeypatch):
    """Issue 27, part 4: the conversion back puts a forecast on the sequence's median skeleton (bone lengths,
    hips, carried joints), which is not the last frame's when the caller's skeleton jitters or the pelvis
    tilts; a model that holds the last pose still starts at the last observed pose, the first forecast frame
    1 / JOIN_FRAMES of the way to the median skeleton's version."""
    rng = np.random.default_rng(0)
    x32 = h36m32() * 1.1 + rng.normal(0.0, 0.005, (50, 32, 3))  # another person, jittery like a lifter
    x = in_layout(world(x32), name)
    y, scene = wild.to_model(x[None], layouts.get_layout(name), wild.up_vector("z"))
    held = np.repeat(y[:, -1:], 25, axis=1)  # a model that holds the last pose
    root, rot = np.repeat(scene.root[:, -1:], 25, axis=1), np.repeat(scene.rot[:, -1:], 25, axis=1)
    out = wild.from_model(held, scene, root, rot, own_frames=False)[0]
    monkeypatch.setattr(wild, "JOIN_FRAMES", 0)
    unjoined = wild.from_model(held, scene, root, rot, own_frames=False)[0]
    last, seen = x[-1], ~np.isnan(x[-1, :, 0])
    assert np.linalg.norm(unjoined[0, seen] - last[seen], axis=-1).mean() > 0.002  # the conversion moves it
    w = np.minimum(np.arange(1, 26) / 5, 1.0)[:, None, None]
    np.testing.assert_allclose(out[:, seen], last[seen] + (unjoined[:, seen] - last[seen]) * w, atol=1e-12)
    np.testing.assert_allclose(out[4:], unjoined[4:], atol=1e-12)


def test_a_joint_never_shown_does_not_carry_the_bones_below_it():
    """3DPW's 13 joints as smpl24 on a larger person: the neck hangs from the root, not from the thorax the
    caller never showed, so whatever the model in-paints for the thorax, the 13 joints of the observation's
    own frames come back exactly (they were measured from the root)."""
    full = in_layout(world(h36m32() * 1.1), "smpl24")
    x = np.full_like(full, np.nan)
    x[:, list(SOMOF13)] = full[:, list(SOMOF13)]
    y, scene = wild.to_model(x[None], layouts.get_layout("smpl24"), wild.up_vector("z"))
    missing = np.isnan(y)
    assert missing[0, 0].any()  # thorax, head, feet, hands
    filled = np.where(missing, np.random.default_rng(1).normal(0.0, 0.3, y.shape), y)
    back = wild.from_model(filled, scene, scene.root, scene.rot, own_frames=True)[0]
    np.testing.assert_allclose(back[:, list(SOMOF13)], x[:, list(SOMOF13)], rtol=0, atol=1e-12)


def test_a_joint_whose_ancestor_a_frame_hides_is_placed_from_an_ancestor_the_frame_shows():
    """random_leg_arm on h36m32 hides the left shoulder, elbow and wrist but not the hand: in those frames the
    hand is placed by the caller's offset from the thorax (times the size ratio, 1 on the model's skeleton), where
    it is with the arm in view, not at the rest pose's distance from the thorax; the arm is missing (in-painted)."""
    full = world(h36m32())
    x = full.copy()
    hidden = np.arange(0, 50, 3)
    for t in hidden:
        x[t, [17, 18, 19, 20]] = np.nan  # 20: the wrist's duplicate
    lay, up = layouts.get_layout("h36m32"), wild.up_vector("z")
    y = wild.to_model(x[None], lay, up)[0][0]
    y_full = wild.to_model(full[None], lay, up)[0][0]
    hand, elbow = list(layouts.MODEL_IDS).index(21), list(layouts.MODEL_IDS).index(18)
    np.testing.assert_allclose(y[:, hand], y_full[:, hand], rtol=0, atol=1e-6)  # the float32 clip: scale 1 +- 1e-7
    assert np.isnan(y[hidden, elbow]).all()
    shown = np.setdiff1d(np.arange(50), hidden)
    np.testing.assert_allclose(y[shown], y_full[shown], rtol=0, atol=1e-12)


def test_a_joint_seen_only_while_its_hip_is_hidden_is_placed_and_repaired_off_the_root():
    """Issue 73, first defect: h36m17, the right hip hidden in frames 0-24 and the right knee in 25-49. The knee
    is placed where it is seen (from the hip's median in the root frame: the hips are rigid in it) and the ankle
    where it is seen (from the hip, by the caller's offset): the model sees what the native layout would show.
    The repair puts the hidden knee near the native repair's, not at the root (it came back at the pelvis,
    447 mm off)."""
    import tcd

    lay, up = layouts.get_layout("h36m17"), wild.up_vector("z")
    full = in_layout(world(h36m32()), "h36m17")
    hip, knee = lay.to32.index(1), lay.to32.index(2)
    x = full.copy()
    x[:25, hip] = np.nan
    x[25:, knee] = np.nan
    y = wild.to_model(x[None], lay, up)[0][0]
    y_full = wild.to_model(full[None], lay, up)[0][0]
    k, ankle = list(layouts.MODEL_IDS).index(2), list(layouts.MODEL_IDS).index(3)
    np.testing.assert_allclose(y[:25, k], y_full[:25, k], rtol=0, atol=1e-6)
    np.testing.assert_allclose(y[:, ankle], y_full[:, ankle], rtol=0, atol=1e-6)
    assert np.isnan(y[25:, k]).all()
    model = tcd.load()
    wild_knee = model.repair(x, capture=Capture("h36m17", fps=25, up="z")).poses[25:, knee]
    assert (np.linalg.norm(wild_knee - full[25:, 0], axis=-1) > 0.25).all()
    native = h36m32()[:, list(layouts.MODEL_IDS)]
    truth = native[25:, k].copy()
    native[25:, k] = np.nan
    native_err = np.linalg.norm(model.repair(native).poses[25:, k] - truth, axis=-1).mean()
    wild_err = np.linalg.norm(wild_knee - full[25:, knee], axis=-1).mean()
    assert wild_err <= 1.05 * native_err


def test_a_joint_the_last_frame_lacks_starts_where_it_was_last_seen(monkeypatch):
    """Issue 27, part 4, occluded rows: a joint hidden in the last frames starts the forecast from its last
    sighting (in that frame's root frame), as Zero-Velocity holds it, and reaches the model's at JOIN_FRAMES."""
    rng = np.random.default_rng(1)
    x = world(h36m32() + rng.normal(0.0, 0.003, (50, 32, 3)))
    wrist = 27  # h36m32's right wrist
    x[-3:, wrist] = np.nan  # hidden in the last 3 frames
    y, scene = wild.to_model(x[None], layouts.get_layout("h36m32"), wild.up_vector("z"))
    root, rot = scene.root[:, -1:], scene.rot[:, -1:]
    sighting = (x[-4, wrist] - scene.root[0, -4]) @ scene.rot[0, -4]  # in frame -4's root frame
    np.testing.assert_allclose(scene.last[0, wrist], sighting, atol=1e-12)
    pose = np.where(np.isnan(y[:, -1:]), y[:, -4:-3], y[:, -1:])  # a model that in-paints the wrist
    held = np.repeat(pose, 25, axis=1)
    root, rot = np.repeat(root, 25, axis=1), np.repeat(rot, 25, axis=1)
    out = wild.from_model(held, scene, root, rot, own_frames=False)[0]
    assert np.isfinite(out).all()
    monkeypatch.setattr(wild, "JOIN_FRAMES", 0)
    unjoined = wild.from_model(held, scene, root, rot, own_frames=False)[0]
    start = sighting @ rot[0, 0].T + root[0, 0]  # the sighting, put on the last root
    w = np.minimum(np.arange(1, 26) / 5, 1.0)[:, None]
    np.testing.assert_allclose(out[:, wrist], start + (unjoined[:, wrist] - start) * w, atol=1e-9)
    assert np.linalg.norm(unjoined[0, wrist] - start) > 1e-3  # the join has something to do


def test_the_last_sighting_is_taken_at_the_callers_frame_rate():
    """At 120 fps a wrist hidden in the last 2 input frames is missing from the last model frame (25 fps:
    a model frame shows a joint only where both input frames around it do); ``sightings`` takes where it was
    last seen from the input frames (2 frames, 17 ms, before the end), not from the model frames (40 ms)."""
    rng = np.random.default_rng(2)
    t = np.arange(120) / 120.0  # the clip's frames as 1 s at 120 fps
    x = world(h36m32(120) + 0.2 * np.sin(2 * np.pi * t)[:, None, None] + rng.normal(0.0, 0.002, (120, 32, 3)))
    wrist = 27
    x[-2:, wrist] = np.nan
    lay, up = layouts.get_layout("h36m32"), wild.up_vector("z")
    xm, _ = wild.resample_to_model(x[None], 120.0, 25.0, 25)
    assert np.isnan(xm[0, -1, wrist]).all()
    _, own_rate = wild.to_model(xm, lay, up)
    _, caller_rate = wild.to_model(xm, lay, up, sightings=x[None])
    canon = wild._canonical(x[None], lay, up, "obs")[2]
    np.testing.assert_allclose(caller_rate.last[0, wrist], canon[0, -3, wrist], atol=1e-12)
    assert np.linalg.norm(own_rate.last[0, wrist] - canon[0, -3, wrist]) > 1e-3  # a model frame further back
    np.testing.assert_array_equal(caller_rate.start[0, wrist], x[-3, wrist])  # time 0, caller coordinates
    np.testing.assert_array_equal(caller_rate.start[0, :wrist], x[-1, :wrist])


def _swapped(x: np.ndarray, name: str) -> np.ndarray:
    """``x`` in layout ``name`` with its left and right joints exchanged (the labels, not the motion)."""
    lay = layouts.get_layout(name)
    names = [layouts.NAMES32[t] if t is not None else None for t in lay.to32]
    order = list(range(lay.num_joints))
    for i, n in enumerate(names):
        if n and n.startswith("left_") and "right_" + n[5:] in names:
            j = names.index("right_" + n[5:])
            order[i], order[j] = j, i
    return x[:, order]


@pytest.mark.parametrize("name", ["h36m17", "smpl24", "coco17"])
def test_left_and_right_swapped_are_told_by_the_knees(tiny_model, name):
    """Issue 73, the left/right trap: the body frame comes from the hips, so swapped labels turn the walker round
    and mirror it, and its bent knees point backward: a MirroredPosesWarning; the walk as given warns nothing."""
    import warnings

    from tcd.exceptions import MirroredPosesWarning

    x = in_layout(world(h36m32()), name)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MirroredPosesWarning)
        tiny_model.forecast(x, capture=Capture(name, up="z"), **FAST)
    with pytest.warns(MirroredPosesWarning, match="left and right are swapped"):
        tiny_model.forecast(_swapped(x, name), capture=Capture(name, up="z"), **FAST)


def test_a_straight_legged_sequence_is_not_called_mirrored():
    """Knees that never bend (a person standing) say nothing about chirality: no verdict either way."""
    lay, up = layouts.get_layout("h36m32"), wild.up_vector("z")
    x = world(np.repeat(h36m32()[:1], 50, axis=0))
    for hip, knee, ankle in wild._LEGS:  # straight legs: knee on the hip-ankle line
        x[:, knee] = 0.5 * (x[:, hip] + x[:, ankle])
    canon = wild._canonical(x[None], lay, up, "obs")[2]
    src = {j: wild._mean_of(canon, lay.source_of(j)) for j in (1, 2, 3, 6, 7, 8)}
    assert not wild.mirrored(src).any()
