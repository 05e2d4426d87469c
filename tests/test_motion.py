"""mvcjax.motion: BVH clips, AnimatedDrawings' files, retargeting, drawn characters moved
by motion capture, and `mvcjax animate`."""

import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import PIL.Image
import pytest

import mvcjax
from mvcjax import motion

DATA = Path(__file__).parent / "data" / "animated_drawings"
EXAMPLES = DATA / "examples"
CHARACTER = EXAMPLES / "characters" / "char1"
MOTION = EXAMPLES / "config" / "motion" / "dab.yaml"
RETARGET = EXAMPLES / "config" / "retarget" / "fair1_ppf.yaml"
BVH = EXAMPLES / "bvh" / "fair1" / "dab.bvh"

TWO_JOINTS = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Arm
  {
    OFFSET 1 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 2 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 0 0 0 0 0 0 0 0
1 2 3 90 0 0 0 0 90
"""


def short_motion(tmp_path, frames: int) -> Path:
    """dab.yaml cut to its first `frames` frames."""
    text = MOTION.read_text().replace("end_frame_idx: 339", f"end_frame_idx: {frames}")
    path = tmp_path / "motion.yaml"
    path.write_text(text.replace("filepath: examples/", f"filepath: {EXAMPLES}/"))
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return motion.Scene.from_files(CHARACTER, short_motion(tmp_path_factory.mktemp("m"), 24),
                                   RETARGET)


def test_a_bvh_file_is_read_into_world_positions(tmp_path):
    path = tmp_path / "two.bvh"
    path.write_text(TWO_JOINTS)
    clip = motion.read_bvh(path)
    assert clip.names == ("Hips", "Arm", "Arm/End Site") and clip.frame_time == 0.5
    np.testing.assert_allclose(clip.positions[0], [[0, 0, 0], [1, 0, 0], [1, 2, 0]], atol=1e-12)
    # Frame 1: the root moved to (1, 2, 3) and turned 90 degrees about z, the arm 90
    # degrees about its own y: its end (0, 2, 0) lies along its y axis, unmoved by that.
    np.testing.assert_allclose(clip.positions[1], [[1, 2, 3], [1, 3, 3], [-1, 3, 3]],
                               atol=1e-12)


def test_a_clip_keeps_its_bone_lengths_at_every_frame():
    clip = motion.read_bvh(BVH)
    assert clip.positions.shape == (339, len(clip.names), 3)
    child = np.flatnonzero(clip.parents >= 0)
    lengths = np.linalg.norm(clip.positions[:, child] - clip.positions[:, clip.parents[child]],
                             axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(
        np.linalg.norm(clip.offsets[child], axis=-1), lengths.shape), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("damage, words", [
    (lambda t: t[:-20], "numbers"),
    (lambda t: t.replace("Frames: 2", "Frames: 3"), "3 frames"),
    (lambda t: t.replace("Xposition", "Wposition"), "unknown channels"),
    (lambda t: t.replace("JOINT Arm", "BONE Arm"), "expected JOINT"),
    (lambda t: t.split("MOTION")[0], "ends early"),
])
def test_a_damaged_bvh_file_is_refused_naming_the_file_and_the_line(tmp_path, damage, words):
    path = tmp_path / "bad.bvh"
    path.write_text(damage(TWO_JOINTS))
    with pytest.raises(motion.BVHError, match="bad.bvh") as error:
        motion.read_bvh(path)
    assert words in str(error.value)


def test_retargeting_matches_animated_drawings_own():
    reference = np.load(DATA / "reference_char1_dab_ppf.npz")
    character = motion.CharacterConfig.read(CHARACTER)
    settings = motion.MotionConfig.read(MOTION)
    clip = motion.read_bvh(settings.bvh, settings.start, settings.stop)
    moved = motion.retarget(character, clip, settings, motion.RetargetConfig.read(RETARGET))
    joints = np.asarray(moved.joints())
    root = character.parents.index(-1)
    np.testing.assert_allclose(joints - joints[:, root:root + 1], reference["joints"],
                               atol=0.01)
    np.testing.assert_allclose(moved.root, reference["roots"], atol=0.01)
    np.testing.assert_allclose(moved.depths, reference["depths"], atol=1e-4)
    # Each bone keeps its rest length: only turned.
    child = np.flatnonzero(np.array(character.parents) >= 0)
    parent = np.array(character.parents)[child]
    lengths = np.linalg.norm(joints[:, child] - joints[:, parent], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(
        np.linalg.norm(moved.rest[child] - moved.rest[parent], axis=-1), lengths.shape),
        rtol=1e-4, atol=1e-3)


def test_joint_angles_drive_the_joints_differentiably():
    character = motion.CharacterConfig.read(CHARACTER)
    settings = motion.MotionConfig.read(MOTION)
    clip = motion.read_bvh(settings.bvh, 0, 2)
    moved = motion.retarget(character, clip, settings, motion.RetargetConfig.read(RETARGET))
    angles = jnp.asarray(moved.angles[1], jnp.float32)
    root = jnp.asarray(moved.root[1], jnp.float32)
    weights = jnp.asarray(np.random.default_rng(0).normal(size=(len(character.names), 2)),
                          jnp.float32)

    def loss(a):
        return jnp.sum(moved.joints(a, root) * weights)

    grad = jax.grad(loss)(angles)
    step = 1e-2
    for k in range(angles.shape[0]):
        bump = jnp.zeros_like(angles).at[k].set(step)
        numeric = (loss(angles + bump) - loss(angles - bump)) / (2 * step)
        np.testing.assert_allclose(grad[k], numeric, rtol=2e-2, atol=0.5)


def test_a_scene_poses_the_drawing_on_its_joints_and_counts_its_folds(scene):
    (actor,) = scene.actors
    (vertices,) = scene.deform()
    assert vertices.shape == (24, actor.drawing.rig.shape_mesh.vertices.shape[0], 2)
    report = actor.report(vertices)
    assert report.joint_miss.shape == (24,) and report.joint_miss.max() < 1.0
    assert report.flipped.shape == (24,) and 0.0 <= report.folded_frames <= 1.0
    pictures = scene.pictures([vertices], size=64, progress=False)
    assert pictures.shape[0] == 24 and max(pictures.shape[1:3]) == 64
    assert pictures.dtype == np.uint8 and pictures[..., 3].max() == 255


def test_draw_order_follows_the_body_parts_depths(scene):
    (actor,) = scene.actors
    ranks = actor.motion.part_order()
    names = actor.drawing.config.names
    parts = actor.motion.parts
    for frame, depth in zip(ranks, actor.motion.depths):
        nearest, farthest = np.argmax(depth), np.argmin(depth)
        top = [frame[names.index(j)] for j in parts[nearest]]
        bottom = [frame[names.index(j)] for j in parts[farthest]]
        assert min(top) > max(bottom)
    faces = np.asarray(actor.drawing.rig.shape_mesh.faces)
    levels = actor.levels(faces, 3)
    assert levels.shape == (3, len(faces)) and levels.max() > levels.min()


def test_a_scene_file_places_its_characters_side_by_side(tmp_path):
    retarget = tmp_path / "left.yaml"
    retarget.write_text(RETARGET.read_text().replace("char_starting_location: [0.0, 0.0, -0.5]",
                                                     "char_starting_location: [-0.6, 0, -1]"))
    path = tmp_path / "scene.yaml"
    path.write_text(f"""scene:
  ANIMATED_CHARACTERS:
    - character_cfg: {CHARACTER}/char_cfg.yaml
      motion_cfg: {short_motion(tmp_path, 4)}
      retarget_cfg: {RETARGET}
    - character_cfg: {CHARACTER}/char_cfg.yaml
      motion_cfg: {short_motion(tmp_path, 4)}
      retarget_cfg: {retarget}
""")
    scene = motion.Scene.read(path)
    assert [a.start[2] for a in scene.actors] == [-1.0, -0.5]  # drawn back to front
    poses = scene.deform()
    unit = max(scene.actors[0].drawing.config.size)
    left, right = (a.to_scene(v, unit) for a, v in zip(scene.actors, poses))
    assert left[..., 0].max() < right[..., 0].max()
    pictures = scene.pictures(poses, size=96, progress=False)
    assert pictures.shape[0] == 4 and pictures.shape[2] == 96


def edited(tmp_path, source: Path, old: str, new: str) -> Path:
    path = tmp_path / source.name
    text = source.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    return path


def test_configs_naming_what_is_not_there_are_refused(tmp_path):
    with pytest.raises(motion.ConfigError, match="projection method 'orthographic'"):
        motion.RetargetConfig.read(edited(tmp_path, RETARGET, "method: pca",
                                          "method: orthographic"))
    bad = edited(tmp_path, RETARGET, "- LeftHand\n", "- LeftPaw\n")
    with pytest.raises(motion.BVHError, match="dab.bvh: has no joint 'LeftPaw'"):
        motion.Scene.from_files(CHARACTER, short_motion(tmp_path, 4), bad)
    with pytest.raises(motion.ConfigError, match="up is"):
        motion.MotionConfig.read(edited(tmp_path, MOTION, "up: +z", "up: -x"))


def character_copy(tmp_path) -> Path:
    folder = tmp_path / "char"
    folder.mkdir()
    for name in ("char_cfg.yaml", "mask.png", "texture.png"):
        (folder / name).write_bytes((CHARACTER / name).read_bytes())
    return folder


def test_a_character_whose_joints_leave_its_mask_or_picture_is_refused(tmp_path):
    folder = character_copy(tmp_path)
    config = folder / "char_cfg.yaml"
    text = config.read_text()
    config.write_text(text.replace("  - 46\n  - 311\n", "  - 2\n  - 3\n"))
    with pytest.raises(motion.ConfigError, match=r"joints \['right_hand'\] lie outside"):
        motion.Drawing.load(folder)
    config.write_text(text.replace("  - 46\n  - 311\n", "  - 46\n  - 900\n"))
    with pytest.raises(motion.ConfigError, match="outside the 508x602 picture"):
        motion.Drawing.load(folder)


def test_a_mask_with_two_blobs_is_refused(tmp_path):
    folder = character_copy(tmp_path)
    mask = np.array(PIL.Image.open(folder / "mask.png"))
    mask[5:25, 5:25] = 255
    PIL.Image.fromarray(mask).save(folder / "mask.png")
    with pytest.raises(motion.ConfigError, match="2 separate blobs"):
        motion.Drawing.load(folder)


def test_animate_command_writes_the_gif_and_reports(tmp_path):
    out = tmp_path / "dab.gif"
    result = subprocess.run([sys.executable, "-m", "mvcjax", "animate", str(CHARACTER),
                             str(short_motion(tmp_path, 12)), str(RETARGET), str(out),
                             "--size", "80", "--progress", "off"],
                            capture_output=True, text=True, check=True)
    assert "joints within" in result.stdout and "folds in" in result.stdout
    with PIL.Image.open(out) as gif:
        assert gif.n_frames == 12 and max(gif.size) == 80


@pytest.mark.parametrize("files, said", [
    (lambda tmp: [CHARACTER / "texture.png", MOTION, RETARGET, tmp / "out.gif"],
     "texture.png: not a character folder or its char_cfg.yaml"),
    (lambda tmp: [CHARACTER, tmp / "nowhere.yaml", RETARGET, tmp / "out.gif"],
     "nowhere.yaml: no such file or folder; give a motion config .yaml"),
    (lambda tmp: [CHARACTER, MOTION, RETARGET, tmp / "out.xyz"],
     "cannot write '.xyz' animations; give a path ending in .gif"),
    (lambda tmp: [MOTION, RETARGET, tmp / "out.gif"], "give SCENE.yaml OUT"),
], ids=["a-picture-for-a-character", "a-missing-config", "an-unknown-suffix", "three-files"])
def test_animate_command_refuses_wrong_files_before_reading_any(files, said, tmp_path, capsys):
    # Checked before anything is read, rigged or compiled: nothing is written, and the
    # message names the file and what to give instead.
    from mvcjax.__main__ import main

    files = files(tmp_path)
    assert main(["animate", *map(str, files)]) == 2
    error = capsys.readouterr().err
    assert error.startswith("mvcjax animate: ") and said in error
    assert not files[-1].exists()


def test_animate_command_refuses_a_truncated_clip_and_writes_nothing(tmp_path):
    clip = tmp_path / "cut.bvh"
    clip.write_text(BVH.read_text()[:-5000])
    settings = tmp_path / "motion.yaml"
    settings.write_text(MOTION.read_text().replace("examples/bvh/fair1/dab.bvh", str(clip)))
    out = tmp_path / "never.gif"
    result = subprocess.run([sys.executable, "-m", "mvcjax", "animate", str(CHARACTER),
                             str(settings), str(RETARGET), str(out)],
                            capture_output=True, text=True)
    assert result.returncode != 0 and "cut.bvh" in result.stderr
    assert "truncated" in result.stderr and not out.exists()


@pytest.mark.float64
def test_the_pose_is_differentiable_in_the_bone_angles(tmp_path):
    scene = motion.Scene.from_files(CHARACTER, short_motion(tmp_path, 6), RETARGET,
                                    dtype=jnp.float64)
    (actor,) = scene.actors
    rig = actor.drawing.rig
    root = jnp.asarray(actor.motion.root[5])
    angles = jnp.asarray(actor.motion.angles[5])
    weights = jnp.asarray(np.random.default_rng(1).normal(
        size=rig.shape_mesh.vertices.shape))

    def loss(a):
        return jnp.sum(rig.deform(actor.drawing.targets(actor.motion.joints(a, root)))
                       * weights)

    grad = jax.jit(jax.grad(loss))(angles)
    loss = jax.jit(loss)
    h = 1e-5
    for k in np.argsort(-np.abs(np.asarray(grad)))[:3]:
        bump = jnp.zeros_like(angles).at[k].set(h)
        numeric = (loss(angles + bump) - loss(angles - bump)) / (2 * h)
        assert abs(float(numeric) - float(grad[k])) < 1e-4 * max(1.0, abs(float(numeric)))


def test_the_picture_is_differentiable_in_the_bone_angles(scene):
    (actor,) = scene.actors
    rig = actor.drawing.rig
    renderer = mvcjax.Renderer.build(rig, actor.drawing.picture, size=(40, 34))
    root = jnp.asarray(actor.motion.root[5], jnp.float32)
    angles = jnp.asarray(actor.motion.angles[5], jnp.float32)

    def red(a):
        targets = actor.drawing.targets(actor.motion.joints(a, root))
        return jnp.sum(renderer(rig.deform(targets), renderer.window)[..., 0])

    grad = jax.jit(jax.grad(red))(angles)
    assert np.all(np.isfinite(grad)) and np.abs(grad).max() > 0


def test_a_bone_that_leaves_the_shape_is_pinned_at_its_ends(tmp_path):
    # An L: a bar up, then right; the skeleton's last bone cuts across the corner.
    mask = np.zeros((120, 120), np.uint8)
    mask[10:110, 10:30] = 255
    mask[10:30, 10:110] = 255
    PIL.Image.fromarray(mask).save(tmp_path / "mask.png")
    PIL.Image.fromarray(np.dstack([mask] * 3)).save(tmp_path / "texture.png")
    joints = [("root", [20, 100], None), ("hip", [20, 100], "root"),
              ("torso", [20, 60], "hip"), ("neck", [100, 20], "torso")]
    (tmp_path / "char_cfg.yaml").write_text("height: 120\nwidth: 120\nskeleton:\n" + "".join(
        f"- loc: [{x}, {y}]\n  name: {name}\n  parent: {parent or 'null'}\n"
        for name, (x, y), parent in joints))
    drawing = motion.Drawing.load(tmp_path)
    # hip -> torso a bone; torso -> neck leaves the L: its end, the neck, a point.
    assert drawing.rows.tolist() == [1, 2, 3]
    assert drawing.rig.handles.count == 3
    rest = motion.CharacterConfig.read(tmp_path).pixels
    targets = np.asarray(drawing.targets(mvcjax.pixels_to_points(rest[:, ::-1], 120)))
    np.testing.assert_allclose(targets, np.asarray(drawing.rig.handle_positions), atol=1e-4)


def test_a_following_window_keeps_the_character_in_the_middle(scene):
    pictures = scene.pictures(size=48, follow=True, progress=False)
    for picture in pictures:
        rows, cols = np.nonzero(picture[..., 3] > 127)
        middle = np.array([rows.min() + rows.max(), cols.min() + cols.max()]) / 2
        np.testing.assert_allclose(middle, (np.array(picture.shape[:2]) - 1) / 2, atol=2)
