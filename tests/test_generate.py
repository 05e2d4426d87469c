"""mvcjax.generate: datasets of posed sprites, written, resumed, shared out, read back."""

import os
import socket
import subprocess
import sys

import jax
import numpy as np
import PIL.Image
import pytest

import mvcjax
from mvcjax import datasets, generate

# Coarse shape meshes: the tests are about the dataset, not about mesh resolution.
RIG = {"shape_spacing": 6.0}


@pytest.fixture(scope="module")
def sprite_folder(tmp_path_factory):
    """The built-in sprite as a PNG with alpha and as a JPEG on white (at half size), a
    file that is not a picture, and a broken picture."""
    folder = tmp_path_factory.mktemp("sprites")
    picture = PIL.Image.fromarray(datasets.sprite_picture())
    picture = picture.resize((picture.width // 2, picture.height // 2), PIL.Image.LANCZOS)
    picture.save(folder / "sprite.png")
    white = PIL.Image.new("RGB", picture.size, "white")
    white.paste(picture, mask=picture.getchannel("A"))
    white.save(folder / "sprite on white.jpg", quality=90)
    (folder / "notes.txt").write_text("not a sprite")
    (folder / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    return folder


@pytest.fixture(scope="module")
def written(sprite_folder, tmp_path_factory):
    out = tmp_path_factory.mktemp("dataset")
    with pytest.warns(UserWarning) as caught:
        report = generate.write_dataset(sprite_folder, out, poses=6, batch=4, size=64,
                                        rig_options=RIG, progress=False)
    return out, report, [str(w.message) for w in caught]


def test_a_folder_of_sprites_is_posed_and_written(written):
    out, report, warned = written
    assert report.sprites == ["sprite on white.jpg", "sprite.png"]
    assert report.written == 12 and report.resumed == 0
    assert sorted(report.skipped) == ["broken.png", "notes.txt"]
    assert any("broken.png" in w and "unreadable" in w for w in warned)
    assert any("notes.txt" in w and "not a picture" in w for w in warned)
    data = generate.read_dataset(out)
    assert sorted(data) == report.sprites
    for name, sprite in data.items():
        t = len(sprite["rest"])
        assert sprite["images"].shape == (6, 64, 64, 4) and sprite["images"].dtype == np.uint8
        np.testing.assert_array_equal(sprite["masks"], sprite["images"][..., 3] >= 128)
        assert sprite["targets"].shape == sprite["keypoints"].shape == (6, t, 2)
        # Inside the picture: the shape never touches its border.
        masks = sprite["masks"]
        assert masks.any(axis=(1, 2)).all()
        assert not (masks[:, 0].any() or masks[:, -1].any() or masks[:, :, 0].any()
                    or masks[:, :, -1].any())
        # The keypoints are the targets in the picture's pixels, and the shape follows
        # its handles there.
        rows = np.clip(np.round(sprite["keypoints"][..., 1]).astype(int), 0, 63)
        cols = np.clip(np.round(sprite["keypoints"][..., 0]).astype(int), 0, 63)
        assert masks[np.arange(6)[:, None], rows, cols].mean() > 0.9, name
        # Random poses: every frame differs from rest and from the others.
        moved = np.linalg.norm(sprite["targets"] - sprite["rest"], axis=-1).max(axis=1)
        assert (moved > 0.5).all()
        assert len({p.tobytes() for p in sprite["images"]}) == 6


def test_a_jpeg_on_white_looks_like_its_png(written):
    # Keyed from its corner colour, with the white taken out of its edge: no light rim.
    # (Their poses differ: a sprite's poses follow its name.)
    data = generate.read_dataset(written[0])
    edge_colours = []
    for name in ("sprite.png", "sprite on white.jpg"):
        images = data[name]["images"]
        assert images[..., 3].max() == 255
        edge = (images[..., 3] > 0) & (images[..., 3] < 255)
        edge_colours.append(images[..., :3][edge].mean(axis=0) / 255)
    assert np.abs(edge_colours[1] - edge_colours[0]).max() < 0.05, edge_colours


def test_an_interrupted_dataset_is_finished_by_running_it_again(sprite_folder, written,
                                                                tmp_path, monkeypatch):
    out = tmp_path / "resumed"
    sprites = [sprite_folder / "sprite.png"]
    calls = []
    write_unit = generate._write_unit

    def interrupted(path, *args):
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        write_unit(path, *args)

    monkeypatch.setattr(generate, "_write_unit", interrupted)
    with pytest.raises(KeyboardInterrupt):
        generate.write_dataset(sprites, out, poses=6, batch=4, size=64, rig_options=RIG,
                               progress=False)
    monkeypatch.setattr(generate, "_write_unit", write_unit)
    first = out / "sprite.png" / "00000.npz"
    assert first.exists() and not (out / "sprite.png" / "00001.npz").exists()
    stamp = first.stat().st_mtime_ns
    report = generate.write_dataset(sprites, out, poses=6, batch=4, size=64,
                                    rig_options=RIG, progress=False)
    assert (report.resumed, report.written) == (4, 2)
    assert first.stat().st_mtime_ns == stamp  # finished work kept as it was
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]  # no leftovers
    # The same dataset as an uninterrupted run.
    whole = generate.read_dataset(written[0])["sprite.png"]
    again = generate.read_dataset(out)["sprite.png"]
    for key in ("images", "masks", "targets", "keypoints"):
        np.testing.assert_array_equal(again[key], whole[key])


@pytest.mark.filterwarnings("ignore:write_dataset skips sprite")
def test_processes_share_the_sprites_and_write_the_same_dataset(sprite_folder, written,
                                                                tmp_path):
    parts = [generate.write_dataset(sprite_folder, tmp_path, poses=6, batch=4, size=64,
                                    rig_options=RIG, progress=False, process_index=i,
                                    process_count=2)
             for i in range(2)]
    assert [p.sprites for p in parts] == [["sprite on white.jpg"], ["sprite.png"]]
    assert sorted(p.name for p in tmp_path.glob("report-*.json")) == ["report-0.json",
                                                                     "report-1.json"]
    one, two = generate.read_dataset(written[0]), generate.read_dataset(tmp_path)
    assert sorted(one) == sorted(two)
    for name in one:
        for key in ("images", "targets"):
            np.testing.assert_array_equal(two[name][key], one[name][key])


@pytest.mark.filterwarnings("ignore:write_dataset skips sprite")
def test_a_folder_with_other_settings_is_refused(sprite_folder, written):
    with pytest.raises(ValueError, match=r"other settings \(poses: 6 there, 8 now\)"):
        generate.write_dataset(sprite_folder, written[0], poses=8, batch=4, size=64,
                               rig_options=RIG, progress=False)


def test_glyphs_with_bones(tmp_path):
    # Bones keep their length and turn within the limit; a pose never folds.
    limits = generate.PoseLimits(offset=0.05, bone_turn=20.0, turn=0.0)

    def bones(shape):
        x0, y0, x1, y1 = shape.bounds
        xm = 0.5 * (x0 + x1)
        return [mvcjax.Bone((xm, y0 + 0.3 * (y1 - y0)), (xm, y0 + 0.7 * (y1 - y0)))]

    sprites = generate.glyph_sprites("I", size=48)
    assert list(sprites) == ["U+0049"]
    report = generate.write_dataset(sprites, tmp_path, poses=4, batch=4, size=48,
                                    limits=limits, handles=bones, progress=False)
    data = generate.read_dataset(tmp_path)["U+0049"]
    assert report.written == 4
    rest_arm = data["rest"][1] - data["rest"][0]
    arms = data["targets"][:, 1] - data["targets"][:, 0]
    np.testing.assert_allclose(np.linalg.norm(arms, axis=-1), np.linalg.norm(rest_arm),
                               rtol=1e-5)
    cross = rest_arm[0] * arms[:, 1] - rest_arm[1] * arms[:, 0]
    turn = np.degrees(np.arctan2(cross, arms @ rest_arm))
    assert np.all(np.abs(turn) <= 20.0 + 1e-3) and np.ptp(turn) > 1.0


def test_pose_limits_are_kept():
    rest = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [5.0, 5.0]])
    limits = generate.PoseLimits(offset=0.1, spread=0.3, turn=0.0, bone_turn=0.0)
    targets = limits.draw(np.random.default_rng(0), rest, np.zeros((0, 2), int),
                          np.zeros(2), 10.0, 2000)
    offsets = targets - rest
    assert np.linalg.norm(offsets, axis=-1).max() <= 1.0 + 1e-12
    # Handles near each other move alike; far ones independently.
    near = np.corrcoef(offsets[:, 0, 0], offsets[:, 1, 0])[0, 1]
    far = np.corrcoef(offsets[:, 0, 0], offsets[:, 3, 0])[0, 1]
    assert near > 0.9 and abs(far) < 0.2
    same = limits.draw(np.random.default_rng(0), rest, np.zeros((0, 2), int),
                       np.zeros(2), 10.0, 2000)
    np.testing.assert_array_equal(same, targets)
    # A turn of the whole pose keeps its shape.
    turned = generate.PoseLimits(offset=0.0, turn=30.0).draw(
        np.random.default_rng(1), rest, np.zeros((0, 2), int), np.zeros(2), 10.0, 50)
    np.testing.assert_allclose(np.linalg.norm(turned, axis=-1),
                               np.broadcast_to(np.linalg.norm(rest, axis=-1), (50, 4)))


@pytest.mark.parametrize("limits, match", [
    (dict(offset=-0.1), "offset=-0.1"),
    (dict(turn=float("nan")), "turn=nan"),
    (dict(spread="wide"), "spread='wide'"),
])
def test_bad_limits_are_refused(limits, match):
    with pytest.raises(ValueError, match=match):
        generate.PoseLimits(**limits)


@pytest.mark.filterwarnings("ignore:write_dataset skips sprite")
def test_bad_arguments_are_refused(sprite_folder, tmp_path):
    with pytest.raises(FileNotFoundError, match="is not a folder"):
        generate.write_dataset(tmp_path / "missing", tmp_path / "out")
    with pytest.raises(ValueError, match="holds no picture"):
        generate.write_dataset(tmp_path, tmp_path / "out")
    (tmp_path / "file").write_text("")
    with pytest.raises(NotADirectoryError, match="is a file"):
        generate.write_dataset(sprite_folder, tmp_path / "file")
    with pytest.raises(ValueError, match="poses"):
        generate.write_dataset(sprite_folder, tmp_path / "out", poses=0)
    with pytest.raises(ValueError, match="process_index"):
        generate.write_dataset(sprite_folder, tmp_path / "out", process_index=2,
                               process_count=2)
    with pytest.raises(TypeError, match="PoseLimits"):
        generate.write_dataset(sprite_folder, tmp_path / "out", limits={"offset": 0.1})
    with pytest.raises(ValueError, match=r"fill must be mvcjax.advanced.Checkerboard\(\) or a"):
        generate.write_dataset(sprite_folder, tmp_path / "out", fill=(2.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="plain file name"):
        generate.write_dataset({"../up": datasets.stick()}, tmp_path / "out")
    with pytest.raises(FileNotFoundError, match="no posed dataset"):
        generate.read_dataset(tmp_path)


def test_a_sprite_that_cannot_be_rigged_is_skipped_and_named(tmp_path):
    def outside(shape):
        return np.array([[1e6, 1e6]])

    with pytest.warns(UserWarning, match="skips sprite stick"), \
            pytest.raises(ValueError, match="No sprite could be posed"):
        generate.write_dataset({"stick": datasets.stick()}, tmp_path, handles=outside,
                               progress=False)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def test_two_processes_with_two_devices_each_write_the_dataset(tmp_path):
    # `mvcjax dataset` as two processes of one jax.distributed job, each with two CPU
    # devices: the same pictures as one process on one device.
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2"
    env = {**os.environ, "XLA_FLAGS": flags,
           "JAX_PLATFORMS": "cpu"}
    command = [sys.executable, "-m", "mvcjax", "dataset", "glyphs", str(tmp_path / "two"),
               "--glyphs", "Lo", "--glyph-size", "48", "--poses", "6", "--batch", "4",
               "--size", "48", "--progress", "off", "--coordinator",
               f"localhost:{_free_port()}", "--num-processes", "2", "--process-id"]
    runs = [subprocess.Popen(command + [str(i)], env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for i in range(2)]
    outputs = [run.communicate(timeout=300) for run in runs]
    assert [run.returncode for run in runs] == [0, 0], outputs
    assert "process 1 of 2, 2 local devices" in outputs[0][0]
    assert "process 2 of 2, 2 local devices" in outputs[1][0]
    generate.write_dataset(generate.glyph_sprites("Lo", size=48), tmp_path / "one",
                           poses=6, batch=4, size=48, progress=False,
                           devices=jax.local_devices()[:1])
    one, two = generate.read_dataset(tmp_path / "one"), generate.read_dataset(tmp_path / "two")
    assert sorted(one) == sorted(two) == ["U+004C", "U+006F"]
    for name in one:
        np.testing.assert_array_equal(two[name]["targets"], one[name]["targets"])
        # Float rounding may differ between the sharded and the single program.
        difference = np.abs(two[name]["images"].astype(int) - one[name]["images"])
        assert difference.max() <= 2, name

