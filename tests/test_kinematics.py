"""The MuJoCo arm agrees with the paper's motion function (Algorithm 1)."""
import numpy as np
import pytest

from apac_mj import suite
from apac_mj.kinematics import angle_grid, motion_function
from apac_mj.suite import planar_arm

LENGTHS = [(5.0, 8.0), (1.0, 1.0), (3.3, 11.7), (7.5, 7.5), (14.0, 0.7)]
ANGLES = np.linspace(0.0, 180.0, 13)  # includes both limits, 15 degree steps


@pytest.fixture(scope="module")
def physics():
    return planar_arm.make_physics()


def test_motion_function_known_values():
    end, elbow = motion_function(0.0, 0.0, 5.0, 8.0)
    np.testing.assert_allclose(end, [28.0, 15.0])
    np.testing.assert_allclose(elbow, [20.0, 15.0])
    end, elbow = motion_function(90.0, 90.0, 5.0, 8.0, origin=(0.0, 0.0))
    np.testing.assert_allclose(elbow, [0.0, 5.0], atol=1e-12)
    np.testing.assert_allclose(end, [-8.0, 5.0], atol=1e-12)
    end, _ = motion_function(0.0, 180.0, 5.0, 8.0)  # the start pose: hand folded back past the shoulder
    np.testing.assert_allclose(end, [12.0, 15.0], atol=1e-12)


def test_motion_function_broadcasts():
    end, elbow = motion_function(np.zeros((4, 3)), 90.0, np.full(3, 2.0), 1.0)
    assert end.shape == elbow.shape == (4, 3, 2)


def test_angle_grid_is_cell_centres():
    grid = angle_grid()
    assert grid.shape == (100, 2)
    centres = np.arange(9.0, 180.0, 18.0)
    np.testing.assert_allclose(np.unique(grid[:, 0]), centres)
    np.testing.assert_allclose(np.unique(grid[:, 1]), centres)
    np.testing.assert_allclose(grid[:10, 0], 9.0)  # shoulder-major


@pytest.mark.parametrize("lengths", LENGTHS)
def test_sites_equal_motion_function_over_angle_grid(physics, lengths):
    physics.set_link_lengths(*lengths)  # set after the model was built
    np.testing.assert_allclose(physics.link_lengths(), lengths)
    worst = 0.0
    for alpha in ANGLES:
        for beta in ANGLES:
            physics.set_joint_angles(alpha, beta)
            end, elbow = motion_function(alpha, beta, *lengths, physics.origin())
            worst = max(worst, np.abs(end - physics.end_effector()).max(), np.abs(elbow - physics.elbow()).max())
    assert worst <= 1e-9


def test_default_model_matches_paper_lengths():
    physics = planar_arm.make_physics()
    np.testing.assert_allclose(physics.link_lengths(), [5.0, 8.0])
    np.testing.assert_allclose(physics.origin(), [15.0, 15.0])


@pytest.mark.parametrize("lengths", [(2.0, 3.0), (6.5, 9.25)])
def test_capsules_follow_link_lengths(physics, lengths):
    """The rendered geometry (capsule centres and half-lengths) follows the new lengths."""
    physics.set_link_lengths(*lengths)
    physics.set_joint_angles(30.0, 60.0)
    shoulder = physics.origin()
    elbow, end = physics.elbow(), physics.end_effector()
    xpos = physics.named.data.geom_xpos
    np.testing.assert_allclose(xpos["upper_arm", :2], (shoulder + elbow) / 2, atol=1e-12)
    np.testing.assert_allclose(xpos["forearm", :2], (elbow + end) / 2, atol=1e-12)
    size = physics.named.model.geom_size
    np.testing.assert_allclose([size["upper_arm", 1], size["forearm", 1]], np.array(lengths) / 2)
    # The capsule axis (local z) points along the link.
    axis = physics.named.data.geom_xmat["forearm"].reshape(3, 3)[:, 2]
    direction = (end - elbow) / np.linalg.norm(end - elbow)
    np.testing.assert_allclose(np.abs(axis[:2] @ direction), 1.0, atol=1e-12)


def test_render_changes_with_link_lengths():
    physics = planar_arm.make_physics()
    physics.set_joint_angles(45.0, 45.0)
    before = physics.render(96, 96, camera_id="overhead")
    physics.set_link_lengths(2.0, 3.0)
    after = physics.render(96, 96, camera_id="overhead")
    assert before.shape == (96, 96, 3)
    assert np.mean(np.any(before != after, axis=-1)) > 0.005  # the arm's pixels moved
    physics.set_link_lengths(5.0, 8.0)
    np.testing.assert_array_equal(physics.render(96, 96, camera_id="overhead"), before)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), "5", True])
def test_bad_link_length_is_rejected(physics, bad):
    with pytest.raises(ValueError, match="link length l1"):
        physics.set_link_lengths(bad, 8.0)
    with pytest.raises(ValueError, match="link length l2"):
        physics.set_link_lengths(5.0, bad)


@pytest.mark.parametrize("angles", [(-1.0, 0.0), (0.0, 180.5), (float("nan"), 0.0)])
def test_bad_joint_angles_are_rejected(physics, angles):
    with pytest.raises(ValueError, match="angle"):
        physics.set_joint_angles(*angles)


def test_links_change_at_run_time_in_a_running_env():
    env = suite.load("planar_arm", "changing_target", task_kwargs={"random": 3})
    env.reset()
    env.physics.set_link_lengths(4.0, 10.0)
    env.step(np.array([50.0, -70.0]))
    alpha, beta = env.physics.joint_angles()
    end, elbow = motion_function(alpha, beta, 4.0, 10.0)
    np.testing.assert_allclose(env.physics.end_effector(), end, atol=1e-9)
    np.testing.assert_allclose(env.physics.elbow(), elbow, atol=1e-9)


def test_documented_physics_accessors():
    """docs/environment.md's example (the accessors a user regression-tests against the motion function) runs
    as written, on a task with another origin too."""
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[1] / "docs" / "environment.md").read_text()
    section = doc[doc.index("**The Physics accessors**"):]
    code = section[section.index("```python\n") + 10:section.index("```\n", section.index("```python\n") + 10)]
    exec(compile(code, "docs/environment.md", "exec"), {})
    moved = code.replace('task_kwargs={"random": 0}', 'task_kwargs={"random": 0, "origin": (10.0, 12.0)}')
    assert moved != code
    exec(compile(moved + "assert np.array_equal(p.origin(), [10.0, 12.0])\n", "docs/environment.md", "exec"), {})
