"""``apac-mj check-kinematics`` (and ``apac-mj tasks --regions``): both outcomes, errors, help."""
import pytest

from apac_mj import cli, kinematics
from apac_mj.suite.kinematics_check import check_kinematics

@pytest.mark.parametrize("actuation", ["servo", "kinematic"])
def test_arm_matches_motion_function(actuation):
    report = check_kinematics(samples=150, seed=1, actuation=actuation)
    assert report.passed
    assert report.worst_end_effector < 1e-12 and report.worst_elbow < 1e-12

def test_same_seed_same_report():
    assert check_kinematics(samples=40, seed=5) == check_kinematics(samples=40, seed=5)

def test_cli_passes(capsys):
    assert cli.main(["check-kinematics", "--samples", "60", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "worst end-effector error" in out and "worst elbow error" in out and "OK" in out
    assert "angle-grid targets in the test region (y >= 22.3 cm, lengths (5.0, 8.0)): 31 of 100" in out

def test_cli_fails_with_a_wrong_motion_function(monkeypatch, capsys):
    true_fn = kinematics.motion_function

    def wrong(alpha, beta, l1, l2, origin=kinematics.DEFAULT_ORIGIN):
        return true_fn(alpha, beta, l1 + 1e-6, l2, origin)  # elbow and hand off by ~1e-6 cm

    monkeypatch.setattr(kinematics, "motion_function", wrong)
    assert cli.main(["check-kinematics", "--samples", "20", "--no-progress", "--actuation", "kinematic"]) == 1
    assert "FAIL" in capsys.readouterr().out
    # A looser tolerance accepts the same error.
    assert cli.main(["check-kinematics", "--samples", "20", "--no-progress", "--tolerance", "1e-5"]) == 0

def test_cli_fails_past_a_zero_tolerance(capsys):
    assert cli.main(["check-kinematics", "--samples", "20", "--no-progress", "--tolerance", "0"]) == 1

@pytest.mark.parametrize("argv, problem", [(["--samples", "0"], "samples must be >= 1"),
                                           (["--tolerance", "-1"], "tolerance must be")])
def test_cli_bad_options(argv, problem, capsys):
    assert cli.main(["check-kinematics", "--no-progress", *argv]) == 2
    assert problem in capsys.readouterr().err

def test_cli_help_explains(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["check-kinematics", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in ("--samples", "--seed", "--tolerance", "--actuation"):
        assert option in out
    assert "motion function" in out

def test_tasks_regions(capsys):
    assert cli.main(["tasks", "--regions"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    from apac_mj.suite.task_spec import task_names

    assert [line.split()[0] for line in lines] == task_names() and len(lines) == 24
    assert all("31/100 grid targets" in line for line in lines)
