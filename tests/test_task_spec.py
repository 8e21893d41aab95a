"""Task files: every shipped file is valid, and malformed files fail naming the problem."""
import numpy as np
import pytest

from apac_mj.util import paths
from apac_mj.suite.task_spec import Region, TaskSpec, TaskSpecError, load_task, load_task_file, task_names

GOOD = """\
description = "a test condition"
[target]
mode = "changing"
region = "train"
zone_radius = 0.75
[kinematics]
mode = "changing"
link_lengths = [4.0, 9]
growth_per_step = 0.002
growth_start_episode = 3
[vision]
mode = "occluded"
[episode]
steps = 12
[plane]
size = [40.0, 30.0]
origin = [20.0, 15.0]
[region]
test_y_min = 21.5
[report]
label = "a test"
short = "tc"
color = "tab:gray"
"""


def write(tmp_path, text, name="cond"):
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def test_every_key_is_read(tmp_path):
    spec = load_task_file(write(tmp_path, GOOD))
    assert spec == TaskSpec(
        name="cond", description="a test condition", target_mode="changing", target_region="train",
        zone_radius=0.75, kinematics_mode="changing", link_lengths=(4.0, 9.0), growth_per_step=0.002,
        growth_start_episode=3, vision="occluded", steps_per_episode=12, plane_size=(40.0, 30.0),
        origin=(20.0, 15.0), region=Region(test_y_min=21.5), report_label="a test", report_short="tc",
        report_color="tab:gray")
    assert spec.occluded


def test_missing_keys_take_paper_defaults(tmp_path):
    spec = load_task_file(write(tmp_path, ""))
    assert (spec.link_lengths, spec.zone_radius, spec.steps_per_episode) == ((5.0, 8.0), 0.5, 30)
    assert (spec.growth_per_step, spec.growth_start_episode, spec.origin) == (0.001, 100, (15.0, 15.0))
    assert (spec.report_label, spec.report_short, spec.report_color) == ("", "", "")


def test_shipped_task_files():
    names = task_names()
    assert len(names) == 24
    for name in names:
        spec = load_task(name)
        assert spec.link_lengths == (5.0, 8.0) and spec.steps_per_episode == 30 and spec.zone_radius == 0.5
        assert (spec.target_mode in name or spec.cued) and spec.region.test_y_min == 22.3
        assert (spec.kinematics_mode == "changing") == ("changing_kinematics" in name)
        assert spec.occluded == name.endswith("occluded")
        assert (spec.target_region == "train") == name.endswith("train_region")
    assert paths.arm_xml_path().is_file()
    noisy, intermittent = load_task("changing_target_noisy"), load_task("changing_target_intermittent")
    assert (noisy.vision, noisy.vision_noise_std, noisy.vision_seen_probability) == ("noisy", 0.5, 1.0)
    assert noisy.observation_noise_std == noisy.zone_radius
    assert (intermittent.vision, intermittent.vision_seen_probability) == ("intermittent", 0.5)
    assert intermittent.observation_noise_std == 0.0 and load_task("changing_target").observation_noise_std == 0.0


def test_shipped_conditions_say_how_the_report_shows_them():
    """The paper's abbreviations (Fig. 4: target / kinematics, s = static, c = changing) and one colour
    per condition, none of them an agent kind's."""
    from apac_mj import kinds
    from apac_mj.experiments.presets import known_conditions

    specs = [load_task(c) for c in known_conditions()]
    assert [s.report_short for s in specs[:4]] == ["ss", "sc", "cs", "cc"]
    assert [s.report_label for s in specs[:4]] == [f"{t} target / {k} kinematics" for t in ("static", "changing")
                                                   for k in ("static", "changing")]
    assert all(s.report_short and s.report_color for s in specs)
    colors = [s.report_color for s in specs]
    assert len(set(colors)) == len(colors) and not set(colors) & {kinds.get(k).color for k in kinds.names()}


@pytest.mark.parametrize("text, std, p", [
    ("[vision]\nmode = 'noisy'\nnoise_std = 0.25", 0.25, 1.0),
    ("[vision]\nmode = 'intermittent'\nseen_probability = 0.3", 0.0, 0.3),
    ("[vision]\nmode = 'intermittent'\nseen_probability = 0.9\nnoise_std = 1", 1.0, 0.9),
])
def test_vision_keys_are_read(tmp_path, text, std, p):
    spec = load_task_file(write(tmp_path, text))
    assert (spec.vision_noise_std, spec.vision_seen_probability, spec.observation_noise_std) == (std, p, std)
    assert isinstance(spec.vision_noise_std, float)


@pytest.mark.parametrize("text, problem", [
    ("colour = 'red'", "unknown top-level key 'colour'"),
    ("[target]\nspeed = 3", r"unknown key target.speed"),
    ("[physics]\ngravity = 0", r"unknown section \[physics\]"),
    ("[target]\nmode = 'wandering'", "target_mode must be one of"),
    ("[target]\nregion = 'north'", "target_region must be one of"),
    ("[target]\nzone_radius = -0.5", "zone_radius must be a positive"),
    ("[target]\nzone_radius = 'big'", "target.zone_radius must be a finite number"),
    ("[kinematics]\nlink_lengths = [5.0]", "kinematics.link_lengths must be a list of two numbers"),
    ("[kinematics]\nlink_lengths = [0.0, 8.0]", r"link_lengths \(l1\) must be a positive"),
    ("[kinematics]\nlink_lengths = [5.0, nan]", "kinematics.link_lengths must be a finite number"),
    ("[kinematics]\ngrowth_per_step = -1e-3", "growth_per_step must be finite and >= 0"),
    ("[kinematics]\ngrowth_start_episode = 1.5", "kinematics.growth_start_episode must be an integer"),
    ("[kinematics]\ngrowth_start_episode = -2", "growth_start_episode must be >= 0"),
    ("[vision]\nmode = 'blurry'", "vision must be one of"),
    ("[vision]\nmode = 'noisy'", r"vision 'noisy' needs vision_noise_std \(\[vision\] noise_std\) > 0"),
    ("[vision]\nmode = 'noisy'\nnoise_std = -0.5", r"\[vision\] noise_std\) must be a finite number >= 0"),
    ("[vision]\nmode = 'noisy'\nnoise_std = 'lots'", "vision.noise_std must be a finite number"),
    ("[vision]\nmode = 'noisy'\nnoise_std = inf", "vision.noise_std must be a finite number"),
    ("[vision]\nmode = 'noisy'\nnoise_std = 0.5\nseen_probability = 0.5",
     r"\[vision\] seen_probability\) must be 1 under vision 'noisy'"),
    ("[vision]\nnoise_std = 0.5", r"\[vision\] noise_std\) must be 0 under vision 'perfect'"),
    ("[vision]\nmode = 'occluded'\nnoise_std = 0.5", r"noise_std\) must be 0 under vision 'occluded'"),
    ("[vision]\nseen_probability = 0.5", r"seen_probability\) must be 1 under vision 'perfect'"),
    ("[vision]\nmode = 'intermittent'", r"vision 'intermittent' needs .*seen_probability\) strictly between"),
    ("[vision]\nmode = 'intermittent'\nseen_probability = 0", r"seen_probability\) must be a number in \(0, 1\]"),
    ("[vision]\nmode = 'intermittent'\nseen_probability = 1.5", r"seen_probability\) must be a number in \(0, 1\]"),
    ("[vision]\nmode = 'intermittent'\nseen_probability = -0.1", r"must be a number in \(0, 1\]"),
    ("[vision]\nmode = 'intermittent'\nseen_probability = true", "vision.seen_probability must be a finite number"),
    ("[episode]\nsteps = 0", "steps_per_episode must be >= 1"),
    ("[episode]\nsteps = true", "episode.steps must be an integer"),
    ("[plane]\norigin = [50.0, 15.0]", "origin .* lies outside the plane"),
    ("[region]\ntest_y_min = 'top'", "region.test_y_min must be a finite number"),
    ("[target\nmode = 'static'", "not valid TOML"),
    ("[report]\ncolour = 'red'", r"unknown key report.colour"),
    ("[report]\ncolor = 'tab:olvie'", r"report_color \(\[report\] color\) 'tab:olvie' is not a matplotlib colour"),
    ("[report]\ncolor = 3", "report.color must be a string"),
    ('[report]\nlabel = "two\\nlines"', r"report_label \(\[report\] label\) must be a one-line string"),
])
def test_bad_file_names_the_problem(tmp_path, text, problem):
    path = write(tmp_path, text)
    with pytest.raises(TaskSpecError, match=problem) as info:
        load_task_file(path)
    assert str(path) in str(info.value)


def test_unknown_task_name_lists_known(tmp_path):
    write(tmp_path, "", "alpha")
    write(tmp_path, "", "beta")
    with pytest.raises(KeyError, match="unknown task 'gamma'; known tasks: alpha, beta"):
        load_task("gamma", tmp_path)
    assert load_task("beta", tmp_path).name == "beta"


def test_replace_checks_overrides():
    spec = load_task("changing_target")
    assert spec.replace(zone_radius=1.0).zone_radius == 1.0
    with pytest.raises(TaskSpecError, match="unknown override"):
        spec.replace(colour="red")
    with pytest.raises(TaskSpecError, match="vision must be one of"):
        spec.replace(vision="x-ray")
    with pytest.raises(TaskSpecError, match="vision 'noisy' needs vision_noise_std"):
        spec.replace(vision="noisy")
    with pytest.raises(TaskSpecError, match=r"vision_noise_std.* must be a finite"):
        spec.replace(vision="noisy", vision_noise_std=float("nan"))
    assert spec.replace(vision="noisy", vision_noise_std=2).observation_noise_std == 2


def test_tasks_command_lists_every_task_and_shows_one(capsys):
    from apac_mj.cli import main
    from apac_mj.suite.task_spec import task_names

    assert main(["tasks"]) == 0
    listed = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert listed == task_names()
    assert main(["tasks", "--show", "static_target_occluded"]) == 0
    shown = dict(line[2:].split(" = ", 1) for line in capsys.readouterr().out.splitlines())
    assert shown["vision"] == "'occluded'" and shown["origin"] == "(15.0, 15.0)" and shown["joint_range"] == "(0.0, 180.0)"
    assert main(["tasks", "--show", "changing_target"]) == 0
    shown = dict(line[2:].split(" = ", 1) for line in capsys.readouterr().out.splitlines())
    assert (shown["report_short"], shown["report_color"]) == ("'cs'", "'tab:olive'")


def test_joint_angles_for_inverts_the_motion_function_inside_the_joint_range():
    """Algorithm 1 forward, then the reach check's inverse: in-range angles that put the hand where it was; a
    point beyond l1 + l2 or reachable only with a joint outside the range has none."""
    from apac_mj.kinematics import motion_function
    from apac_mj.suite.task_spec import joint_angles_for

    rng = np.random.default_rng(0)
    for a, b in rng.uniform(5.0, 175.0, size=(50, 2)):
        end, _ = motion_function(a, b, 10.0, 8.0, (0.0, 0.0))
        found = joint_angles_for(end[0], end[1], 10.0, 8.0, (0.0, 180.0))
        assert found is not None and all(0.0 <= v <= 180.0 for v in found)
        np.testing.assert_allclose(motion_function(*found, 10.0, 8.0, (0.0, 0.0))[0], end, atol=1e-9)
    assert joint_angles_for(18.5, 0.0, 10.0, 8.0, (0.0, 180.0)) is None  # beyond reach
    assert joint_angles_for(0.0, -12.0, 10.0, 8.0, (0.0, 180.0)) is None  # below the shoulder: a joint < 0
