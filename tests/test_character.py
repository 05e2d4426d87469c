"""Layered characters: a rig per layer posed by one set of handles, attachments, draw
order per frame, layered files, and the errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

import mvcjax
from mvcjax import datasets
from mvcjax.rig import parse_handles

BODY, LEFT_ARM, RIGHT_ARM, HAND = range(4)


@pytest.fixture(scope="module")
def layers():
    return datasets.layered_figure()


@pytest.fixture(scope="module")
def character(layers):
    return mvcjax.Character.build(layers, datasets.layered_figure_handles())


@pytest.fixture(scope="module")
def renderer(character, layers):
    return mvcjax.Renderer.build(character, layers)


@pytest.fixture(scope="module")
def wave():
    return datasets.layered_figure_wave(30)


@pytest.fixture(scope="module")
def posed(character, wave):
    return mvcjax.deform_frames(character, wave)


def test_handles_pin_the_parts_they_lie_in_and_the_hand_follows_its_arm(character):
    # The chest and the ankles pin the body, each arm's bone its arm as a bone and the
    # body at the shoulder; the right hand holds none and follows the right arm.
    assert character.names == ("body", "left arm", "right arm", "right hand")
    assert character.parents == (-1, -1, -1, RIGHT_ARM)
    assert character.order.index(RIGHT_ARM) < character.order.index(HAND)
    counts = [int(feed.rest.shape[0]) for feed in character.feeds]
    assert counts == [5, 2, 2, 0]  # chest, two shoulders, two ankles; a bone each; none
    assert character.parts[HAND].handles.count >= 2  # pinned where it overlaps the arm
    assert character.attachments[HAND] is not None


def test_rest_targets_give_the_rest_parts(character):
    parts = character.deform(character.handle_positions)
    for part, rig in zip(parts, character.parts):
        rest = rig.shape_mesh.vertices
        size = float(jnp.max(rest) - jnp.min(rest))
        assert float(jnp.max(jnp.abs(part - rest))) < 1e-4 * size


def test_a_swung_arm_leaves_the_body_where_it_was_and_carries_the_hand(character, posed,
                                                                         wave):
    # The body is pinned by the chest, the ankles and the shoulders, none of which move.
    body = posed[BODY] - character.parts[BODY].shape_mesh.vertices
    assert float(jnp.max(jnp.abs(body))) < 1e-3
    # The hand keeps its place at the arm's tip: its centre stays as far from the wrist
    # target as at rest (the arm turned about the shoulder, rigidly).
    hand = posed[HAND].mean(axis=1)
    reach = jnp.linalg.norm(hand - wave[:, 4], axis=1)
    assert float(jnp.max(jnp.abs(reach - reach[0]))) < 0.05 * float(reach[0])
    turned = jnp.linalg.norm(hand[15] - hand[0])
    assert float(turned) > 50.0  # it did move, far


def test_deform_frames_jit_and_vmap_agree_with_single_poses(character, posed, wave):
    single = character.deform(wave[9])
    batched = jax.jit(jax.vmap(character.deform))(jnp.asarray(wave[8:10]))
    for whole, one, mapped in zip(posed, single, batched):
        np.testing.assert_allclose(whole[9], one, atol=1e-3)
        np.testing.assert_allclose(mapped[1], one, atol=1e-3)


def test_new_targets_and_new_orders_do_not_recompile(character, renderer, wave):
    deform = jax.jit(mvcjax.Character.deform)
    draw = jax.jit(lambda r, v, o: r(v, o))
    for k in (3, 6):
        parts = deform(character, jnp.asarray(wave[k]))
        draw(renderer, parts, jnp.asarray([k % 4, *[i for i in range(4) if i != k % 4]]))
    assert deform._cache_size() == 1
    assert draw._cache_size() == 1


def test_new_weights_change_every_part_without_recompiling(character, wave):
    deform = jax.jit(lambda c, t: c.deform(t))
    # The chest pulled up against the shoulders and ankles: with handles that pull a
    # hundredth as hard, the body gives less.
    soft = character.with_weights(mvcjax.Weights(handle=1.0))
    targets = jnp.asarray(wave[12]).at[0, 1].add(20.0)
    firm, loose = deform(character, targets), deform(soft, targets)
    assert deform._cache_size() == 1
    assert float(jnp.max(jnp.abs(loose[BODY] - firm[BODY]))) > 1.0


def _alpha(part_renderer, vertices):
    return np.asarray(part_renderer(vertices))[..., 3]


def test_a_swing_across_the_torso_changes_only_the_pixels_the_arm_passes(character, layers,
                                                                         renderer, posed):
    # Pixels that neither the right arm nor its hand covers, now or at rest, keep their
    # colour in every frame; where the arm's edge lies over the torso, the picture is its
    # antialiased coverage blended over the torso (no torso patch above it, no steps).
    pictures = renderer.frames(posed).astype(np.float64) / 255
    # Each part drawn alone, as a rig of its own, its triangles on one level as in the
    # character's picture.
    parts = [mvcjax.Renderer.build(rig, layer.picture,
                                   depth=np.zeros(rig.shape_mesh.vertices.shape[0]))
             for rig, layer in zip(character.parts, layers)]
    moving = [RIGHT_ARM, HAND]
    rest_cover = sum(_alpha(parts[i], posed[i][0]) for i in moving)
    blended = 0
    for k in range(len(pictures)):
        cover = rest_cover + sum(_alpha(parts[i], posed[i][k]) for i in moving)
        still = cover == 0
        assert np.abs(pictures[k] - pictures[0])[still].max() <= 1 / 255
        arm = np.asarray(parts[RIGHT_ARM](posed[RIGHT_ARM][k]))
        body = np.asarray(parts[BODY](posed[BODY][k]))
        hand = _alpha(parts[HAND], posed[HAND][k])
        left = _alpha(parts[LEFT_ARM], posed[LEFT_ARM][k])
        edge = (arm[..., 3] > 0.05) & (arm[..., 3] < 0.95) & (body[..., 3] == 1) & \
            (hand == 0) & (left == 0)
        a = arm[..., 3:]
        expected = a * arm[..., :3] + (1 - a) * body[..., :3]
        assert np.abs(pictures[k][..., :3] - expected)[edge].max() <= 1.5 / 255
        blended += int(edge.sum())
    assert blended > 100  # the arm's edge did cross the torso, and was blended there


def test_the_draw_order_can_change_per_frame(character, renderer, posed, layers):
    # At rest the left arm lies over the torso's side: drawn over it by default, under
    # it with the body last.
    rest = [p[0] for p in posed]
    overlap = (layers[BODY].picture[..., 3] > 0.5) & (layers[LEFT_ARM].picture[..., 3] > 0.5)
    sleeve = layers[LEFT_ARM].picture[overlap][:, :3].mean(axis=0)
    shirt = layers[BODY].picture[overlap][:, :3].mean(axis=0)
    default = np.asarray(renderer(rest))[overlap][:, :3].mean(axis=0)
    behind = np.asarray(renderer(rest, order=[1, 2, 3, 0]))[overlap][:, :3].mean(axis=0)
    np.testing.assert_allclose(default, sleeve, atol=0.02)
    np.testing.assert_allclose(behind, shirt, atol=0.02)
    orders = np.array([[0, 1, 2, 3], [1, 2, 3, 0]])
    pictures = renderer.frames([p[:2] for p in posed], order=orders)
    assert not np.array_equal(pictures[0], pictures[1])


def test_gradients_flow_from_the_picture_to_the_targets(character, renderer, wave):
    targets = jnp.asarray(wave[10])

    def hand_x(t):
        return jnp.mean(character.deform(t)[HAND][:, 0])

    grad = jax.jit(jax.grad(hand_x))(targets)
    # Only the right wrist's target and the shoulder (its bone's pivot) move the hand.
    assert float(jnp.abs(grad[4]).sum()) > 0.1
    assert float(jnp.abs(grad[jnp.array([0, 5, 6])]).max()) < 1e-3
    picture = jax.jit(jax.grad(lambda t: jnp.sum(renderer(character.deform(t))[..., 0])))(
        targets)
    assert np.all(np.isfinite(picture)) and float(jnp.abs(picture[4]).sum()) > 0


@pytest.mark.float64
def test_gradients_match_finite_differences(layers):
    character = mvcjax.Character.build(layers, datasets.layered_figure_handles(),
                                       shape_spacing=6.0, dtype=jnp.float64)
    targets = jnp.asarray(datasets.layered_figure_wave(5)[1])
    weights = jax.random.normal(jax.random.key(0), character.parts[HAND].shape_mesh.vertices.shape)

    def loss(t):
        return jnp.sum(character.deform(t)[HAND] * weights)

    grad = jax.jit(jax.grad(loss))(targets)
    loss = jax.jit(loss)
    h = 1e-4
    for row, axis in [(4, 0), (4, 1), (3, 1)]:
        step = jnp.zeros_like(targets).at[row, axis].set(h)
        fd = (loss(targets + step) - loss(targets - step)) / (2 * h)
        assert abs(float(fd) - float(grad[row, axis])) < 1e-5 * max(1.0, abs(float(fd)))


def _write_psd(path, layers, opacity=None, multiply=None):
    from psd_tools import PSDImage
    from psd_tools.api.layers import PixelLayer
    from psd_tools.constants import BlendMode

    rows, cols = layers[0].picture.shape[:2]
    psd = PSDImage.new("RGBA", (cols, rows))
    for layer in layers:
        image = Image.fromarray(mvcjax.export.to_uint8(layer.picture), "RGBA")
        # Cropped to its opaque part and placed by its offset, as Photoshop stores layers.
        left, top, right, bottom = image.getbbox()
        written = PixelLayer.frompil(image.crop((left, top, right, bottom)), psd, layer.name,
                                     top=top, left=left)
        if layer.name == opacity:
            written.opacity = 128
        if layer.name == multiply:
            written.blend_mode = BlendMode.MULTIPLY
        psd.append(written)
    psd.save(path)


def _write_ora(path, layers, opacity=None, multiply=None):
    import pyora

    rows, cols = layers[0].picture.shape[:2]
    project = pyora.Project.new(cols, rows)
    for layer in layers:
        project.add_layer(Image.fromarray(mvcjax.export.to_uint8(layer.picture), "RGBA"),
                          layer.name, opacity=128 / 255 if layer.name == opacity else 1.0,
                          composite_op="svg:multiply" if layer.name == multiply
                          else "svg:src-over")
    project.save(path)


@pytest.mark.parametrize("write", [_write_psd, _write_ora], ids=["psd", "ora"])
def test_layered_files_read_back_as_their_layers(tmp_path, layers, write):
    path = tmp_path / f"figure.{write.__name__[-3:]}"
    write(path, layers)
    back = mvcjax.load_layers(path)
    assert [layer.name for layer in back] == [layer.name for layer in layers]
    for read, drawn in zip(back, layers):
        np.testing.assert_allclose(read.picture, drawn.picture, atol=0.5 / 255)


@pytest.mark.parametrize("write", [_write_psd, _write_ora], ids=["psd", "ora"])
def test_a_layers_opacity_scales_its_alpha_and_other_blend_modes_are_named(tmp_path, layers,
                                                                         write):
    path = tmp_path / f"figure.{write.__name__[-3:]}"
    write(path, layers, opacity=layers[1].name, multiply=layers[2].name)
    with pytest.warns(UserWarning, match=f"{layers[2].name!r} \\(multiply\\)"):
        back = mvcjax.load_layers(path)
    np.testing.assert_allclose(back[1].picture[..., 3], layers[1].picture[..., 3] * 128 / 255,
                               atol=1 / 255)
    np.testing.assert_allclose(back[0].picture, layers[0].picture, atol=0.5 / 255)


def test_a_character_builds_from_a_psd_file(tmp_path, layers, character):
    path = tmp_path / "figure.psd"
    _write_psd(path, layers)
    from_file = mvcjax.Character.build(path, datasets.layered_figure_handles())
    assert from_file.names == character.names
    assert [p.shape_mesh.vertices.shape for p in from_file.parts] == \
        [p.shape_mesh.vertices.shape for p in character.parts]


def _disc(centre, radius, size=(64, 64)):
    y, x = np.mgrid[:size[0], :size[1]]
    picture = np.zeros((*size, 4), np.float32)
    picture[(x - centre[0]) ** 2 + (y - centre[1]) ** 2 < radius**2] = (1, 0, 0, 1)
    return picture


def test_bad_layers_and_handles_are_refused_with_the_fix(tmp_path):
    a, b = _disc((20, 32), 12), _disc((44, 32), 12)
    with pytest.raises(ValueError, match="share one canvas"):
        mvcjax.load_layers([a, _disc((20, 20), 10, (32, 32))])
    with pytest.raises(ValueError, match="'layer 1' is empty"):
        mvcjax.load_layers([a, np.zeros_like(a)])
    broken = tmp_path / "broken.psd"
    broken.write_bytes(b"not a photoshop file")
    with pytest.raises(ValueError, match="could not be read as PSD"):
        mvcjax.load_layers(broken)
    with pytest.raises(FileNotFoundError, match="No layered file"):
        mvcjax.load_layers(tmp_path / "missing.ora")
    with pytest.raises(ValueError, match="not a layered file"):
        mvcjax.load_layers(tmp_path / "figure.png")
    # Pixel (row, col) is at (col, rows - 1 - row): the discs' centres.
    left, right = (20.0, 31.0), (44.0, 31.0)
    with pytest.raises(ValueError, match=r"handles\[1\] .* lies in no part"):
        mvcjax.Character.build([a, b], [left, (32.0, 60.0)])
    with pytest.raises(ValueError, match="'layer 1' holds no handle and overlaps no other"):
        mvcjax.Character.build([a, b], [left, (14.0, 31.0)])
    eyes = np.maximum(_disc((20, 32), 4), _disc((44, 32), 4))
    with pytest.raises(ValueError, match="'layer 1' holds 2 separate regions"):
        mvcjax.Character.build([a, eyes], [left])
    faint = a * np.array([1, 1, 1, 0.3], np.float32)
    with pytest.raises(ValueError, match="layer 'layer 1': alpha is at or below 0.5"):
        mvcjax.Character.build([a, faint], [left])
    with pytest.raises(ValueError, match="attach names a part 'nose'"):
        mvcjax.Character.build([a, b], [left, right], attach={"nose": 0})
    with pytest.raises(ValueError, match="'layer 0', 'layer 1' follow each other in a loop"):
        mvcjax.Character.build([a, b], [left, right], attach={0: 1, 1: 0})


def test_bones_meeting_at_a_joint_pin_a_third_part_there_once():
    # An upper and a lower bone meet at an elbow that a patch (a third part) covers: the
    # patch holds neither bone, only the joint, which both bones put at one spot.
    canvas = (64, 96)
    upper, lower = np.zeros((*canvas, 4), np.float32), np.zeros((*canvas, 4), np.float32)
    upper[26:38, 8:52] = (1, 0, 0, 1)
    lower[26:38, 44:88] = (0, 0, 1, 1)
    patch = _disc((48, 31), 5, canvas)
    shoulder, elbow, wrist = (12.0, 31.5), (48.0, 31.5), (84.0, 31.5)
    character = mvcjax.Character.build(
        [upper, lower, patch], [mvcjax.Bone(shoulder, elbow), mvcjax.Bone(elbow, wrist)])
    assert character.parts[2].handles.count == 1
    targets = np.asarray(character.handle_positions).copy()
    targets[2:] = (48.0, 31.5), (48.0, 67.5)  # the forearm turned up about the elbow
    parts = character.deform(targets)
    centre = np.asarray(parts[2]).mean(axis=0)
    np.testing.assert_allclose(centre, elbow, atol=1.0)  # the patch stays on the elbow


def test_order_and_vertices_must_fit_the_parts(character, renderer, wave):
    parts = character.deform(wave[0])
    with pytest.raises(ValueError, match="order must list each of the 4 parts once"):
        renderer(parts, order=[0, 0, 1, 2])
    with pytest.raises(ValueError, match="a tuple of 4 arrays"):
        renderer(parts[0])
    with pytest.raises(ValueError, match=r"targets must have shape \(7, 2\)"):
        character.deform(wave[0][:5])


def test_the_character_and_its_parts_are_described(character):
    text = repr(character)
    assert "4 parts" in text and "'right hand'" in text and "follows 'right arm'" in text
    rest, _, _ = parse_handles(datasets.layered_figure_handles())
    np.testing.assert_allclose(character.handle_positions, rest, atol=1e-4)


def test_fit_targets_finds_a_characters_pose_from_its_picture(character, layers, wave):
    # Drawn small, the arm turned 24 degrees; fitted from rest, coarse to fine.
    renderer = mvcjax.Renderer.build(character, layers, size=(65, 60))
    true = jnp.asarray(wave[2])
    picture = np.asarray(renderer(character.deform(true)))
    with pytest.warns(RuntimeWarning, match="did not converge"):  # few steps, to be quick
        result = mvcjax.fit_targets(character, renderer, picture, steps=15, blurs=(3.0, 0.0))
    pixel = 4.0  # units per pixel
    for fitted, drawn in zip(character.deform(result.targets), character.deform(true)):
        assert float(jnp.max(jnp.abs(fitted - drawn))) < 0.25 * pixel
    # The renderer of the joined parts (in the layers' order) draws the same picture.
    loss = mvcjax.image_loss(character, renderer, true, picture)
    assert float(mvcjax.image_loss(character, renderer.mesh, true, picture)) == float(loss)
    with pytest.raises(TypeError, match="renderer must be an mvcjax.Renderer"):
        mvcjax.image_loss(character, layers, true, picture)
    with pytest.raises(ValueError, match="renderer was built for"):
        mvcjax.image_loss(character, mvcjax.Renderer.build(character.parts[0]), true, picture)


def test_interact_drags_a_character_and_records_it(character, layers, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.backend_bases import MouseEvent

    def mouse(posing, kind, point):
        x, y = posing.axes.transData.transform(np.asarray(point, np.float64))
        MouseEvent(f"{kind}_event", posing.figure.canvas, x, y, button=1)._process()

    try:
        with pytest.warns(UserWarning):  # Agg shows no window, and says so
            posing = mvcjax.interact(character, layers, record=True)
        posing.figure.canvas.draw()
        wrist = posing.targets[4].copy()
        path = [wrist + k * np.array([-6.0, 5.0]) for k in range(1, 5)]
        mouse(posing, "button_press", wrist)
        for point in path:
            mouse(posing, "motion_notify", point)
        mouse(posing, "button_release", path[-1])
        assert posing.updates == len(path)
        assert "add a pin" not in posing.axes.get_title()  # its pins are its handles
        with pytest.raises(ValueError, match="no spare pins"):
            posing.add_pin(posing.shape_vertices[0])
        expected = jnp.concatenate(character.deform(posing.targets))
        np.testing.assert_allclose(posing.shape_vertices, expected, atol=1e-3)
        drawn = mvcjax.export.to_uint8(posing.renderer(character.deform(posing.targets)))
        assert np.abs(posing.picture.astype(int) - drawn.astype(int)).max() <= 1
        frames = posing.frames()
        assert frames.shape == (len(path) + 1, character.shape_mesh.vertices.shape[0], 2)
        posing.write_animation(tmp_path / "drag.gif", fps=10)
        assert (tmp_path / "drag.gif").stat().st_size > 1000
    finally:
        plt.close("all")


def test_a_posed_character_exports_as_one_mesh_and_its_outlines(character, posed, tmp_path):
    mesh = character.shape_mesh
    frame = jnp.concatenate([part[15] for part in posed])
    rings = mvcjax.export.outline_rings(frame, mesh.faces)
    assert len(rings) == len(character.parts)  # one outline per part, none merged
    mvcjax.export.write_svg(tmp_path / "pose.svg", rings)
    mvcjax.export.write_obj(tmp_path / "pose.obj", frame, mesh.faces)
    lines = (tmp_path / "pose.obj").read_text().splitlines()
    assert sum(line.startswith("v ") for line in lines) == mesh.vertices.shape[0]
    assert sum(line.startswith("f ") for line in lines) == mesh.faces.shape[0]
    assert (tmp_path / "pose.svg").read_text().count("<path") >= 1


def test_an_eager_deform_is_one_compiled_program(character, wave, caplog):
    # Outside jit, solving and skinning every part runs one program, compiled on the
    # first call and reused by the next with new targets, as a rig's deform does.
    first = character.deform(wave[3])
    with jax.log_compiles(True), caplog.at_level("WARNING", logger="jax"):
        again = [character.deform(wave[k]) for k in (4, 5)]
    assert not [m for m in caplog.messages if "Finished XLA compilation" in m]
    for parts in [first, *again]:
        assert all(bool(jnp.all(jnp.isfinite(p))) for p in parts)
    expected = jax.jit(character.deform)(wave[5])
    for part, want in zip(again[-1], expected):
        np.testing.assert_allclose(part, want, rtol=0, atol=1e-3)


def test_warm_started_frames_start_each_from_the_pose_before(character, wave):
    # As a rig's (tests/test_animation.py): the first frame from the character's start,
    # every part's turned start carried by its parent's. Warm starting is one scan for
    # every solver: the default's programs here (a character's FoldFree from the pose
    # before is the interact test's).
    frames = jnp.asarray(wave[:4])
    posed = mvcjax.deform_frames(character, frames, warm_start=True)
    control = character.start(frames[0])
    assert control.shape == character.control_mesh.vertices.shape
    for k, targets in enumerate(frames):
        solved = character.solve(targets, init=control)
        control = character.joined(solved)
        for whole, part in zip(posed, character.skin(solved)):
            np.testing.assert_allclose(whole[k], part, atol=1e-3)
    flipped = mvcjax.flipped_triangles(character.shape_mesh.vertices,
                                       character.joined(posed), character.shape_mesh.faces)
    assert int(np.sum(flipped)) == 0


def test_out_is_refused_for_a_character_with_what_to_do(character, posed, wave):
    with pytest.raises(ValueError, match="leave out out="):
        mvcjax.deform_frames(character, wave, out=jnp.zeros_like(character.joined(posed)))
    with pytest.raises(ValueError, match="init must have the control mesh's shape"):
        character.deform(wave[0], init=character.control_mesh.vertices[:-1])
    with pytest.raises(TypeError, match="init must be a start"):
        character.solve(wave[0], init="bent")


@pytest.fixture(params=["rig", "character"])
def subject(request, horse_rig32, character):
    """Either kind of subject the tools take (`mvcjax.advanced.AbstractRig`)."""
    return {"rig": horse_rig32, "character": character}[request.param]


def test_a_rig_and_a_character_offer_one_protocol(subject):
    assert isinstance(subject, mvcjax.advanced.AbstractRig)
    targets = subject.handle_positions + 2.0
    control = subject.solve(targets)
    joined = subject.joined(subject.deform(targets))
    assert joined.shape == subject.shape_mesh.vertices.shape
    assert subject.joined(control).shape == subject.control_mesh.vertices.shape
    np.testing.assert_allclose(subject.joined(subject.skin(control)), joined, atol=1e-3)
    # From the joined control vertices, the solve is where it was.
    again = subject.joined(subject.deform(targets, init=subject.joined(control)))
    np.testing.assert_allclose(again, joined, atol=0.05)
    assert subject.start(targets).shape == subject.control_mesh.vertices.shape
    frames = subject.joined(mvcjax.deform_frames(subject, jnp.stack([targets, targets])))
    np.testing.assert_allclose(frames[1], joined, atol=1e-3)
    assert int(np.sum(mvcjax.flipped_triangles(subject.shape_mesh.vertices, joined,
                                               subject.shape_mesh.faces))) == 0


def test_interact_poses_either_from_the_pose_before_with_fold_free(subject):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    solver = mvcjax.FoldFree()
    try:
        with pytest.warns(UserWarning):  # Agg shows no window, and says so
            posing = mvcjax.interact(subject, solver=solver, spare_pins=0)
        targets = np.asarray(subject.handle_positions) + 3.0
        posing.set_targets(targets)
        cold = subject.joined(subject.deform(targets, solver))
        np.testing.assert_allclose(posing.shape_vertices, cold, atol=0.05)
        assert posing.folds == 0
    finally:
        plt.close("all")
