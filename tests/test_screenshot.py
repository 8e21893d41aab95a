"""``apac-mj screenshot``: the viewer headless, without a hover tooltip over the arm (issue 29, item 4)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from apac_mj.cli import main
from apac_mj.recording import screenshot as S


@pytest.mark.parametrize("window", [(1400, 800), (1200, 700), (1920, 1080), (200, 200), (800, 3000)])
def test_the_pointer_starts_outside_the_window(window: tuple[int, int]) -> None:
    """Xvfb starts the pointer at its screen's centre; the viewer (at the top-left, drawn at up to twice its
    size) shows a tooltip where the pointer rests: the centre must lie beyond it on both axes."""
    g = S.geometry(window)
    px, py = g.pointer
    assert px > S.MAX_SCALE * window[0] and py > S.MAX_SCALE * window[1]
    assert g.pointer_outside_window()


def test_xvfb_runs_own_screen_would_put_the_pointer_on_the_window() -> None:
    """The property tested above fails for the screen the old documented command had (the window's size)."""
    assert not S.Geometry((1400, 800), (1400, 800)).pointer_outside_window()


def test_the_command_sizes_the_virtual_screen() -> None:
    argv = S.command("a.rrd", "b.png", (1400, 800), viewer="rerun")
    g = S.geometry((1400, 800))
    assert argv[:4] == ["xvfb-run", "-a", "-s", f"-screen 0 {g.screen[0]}x{g.screen[1]}x24"]
    assert argv[4:] == ["rerun", "a.rrd", "--window-size", "1400x800", "--screenshot-to", "b.png"]


def test_the_docs_use_the_command() -> None:
    """The documented headless screenshot is this command, not a bare ``xvfb-run ... rerun`` (which gave a
    tooltip in 5 of 5 screenshots)."""
    root = Path(__file__).resolve().parents[1]
    blocks = "".join((root / "docs" / "recording.md").read_text().split("```")[1::2])  # the code blocks
    assert "apac-mj screenshot" in blocks
    assert "xvfb-run -a rerun" not in blocks


@pytest.mark.parametrize("size", ["12", "1400x", "axb", "100x800", "1400x800x2"])
def test_bad_window_sizes_are_refused(size: str) -> None:
    with pytest.raises(ValueError, match="--window-size"):
        S.parse_window_size(size)


def test_errors_name_the_problem_and_write_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["screenshot", str(tmp_path / "missing.rrd"), "--out", str(tmp_path / "s.png")]) != 0
    assert "does not exist" in capsys.readouterr().err
    rrd = tmp_path / "r.rrd"
    rrd.write_bytes(b"not a recording")
    assert main(["screenshot", str(rrd), "--out", str(tmp_path / "s.jpg")]) != 0
    assert "must end in .png" in capsys.readouterr().err
    monkeypatch.setenv("PATH", str(tmp_path))  # no xvfb-run
    assert main(["screenshot", str(rrd), "--out", str(tmp_path / "s.png")]) != 0
    assert "xvfb-run was not found" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd"]


def dark_fraction_over_plane(png: Path) -> float:
    """The fraction of near-black pixels where the blueprint puts the plane view (a tooltip is a dark box:
    20% there with the tooltip, 0.5% without, measured on 2800x1600 screenshots)."""
    import imageio.v3 as iio

    a = iio.imread(png)[..., :3].astype(int)
    h, w = a.shape[:2]
    region = a[int(0.11 * h):int(0.66 * h), int(0.30 * w):int(0.615 * w)]
    return float((region.max(-1) < 45).mean())


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="needs xvfb-run and a Vulkan/OpenGL driver")
def test_a_real_screenshot_has_no_tooltip_over_the_plane(tmp_path: Path) -> None:
    from apac_mj.recording.record import record

    rrd = record(tmp_path / "r.rrd", episodes=2, progress=False).rrd
    png = S.screenshot(rrd, tmp_path / "s.png")
    assert dark_fraction_over_plane(png) < 0.03
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd", "s.png"]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The bytes of a one-episode recording (made once for the module)."""
    from apac_mj.recording.record import record

    return record(tmp_path_factory.mktemp("rec") / "good.rrd", episodes=1, progress=False).rrd.read_bytes()


def _a_recording(tmp_path: Path, recorded: bytes) -> Path:
    (tmp_path / "good.rrd").write_bytes(recorded)
    return tmp_path / "good.rrd"


@pytest.mark.parametrize("damage", ["empty", "first 1000 bytes", "random bytes", "json named .rrd", "cut short"])
def test_a_file_the_viewer_cannot_load_is_refused_before_it_starts(tmp_path: Path, damage: str, recorded: bytes,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """F6 (issue 45): the viewer showed its error page for these, and its screenshot was reported written."""
    good = _a_recording(tmp_path, recorded).read_bytes()
    data = {"empty": b"", "first 1000 bytes": good[:1000], "random bytes": np.random.default_rng(0).bytes(200_000),
            "json named .rrd": b'{"episodes": 2}\n', "cut short": good[: len(good) // 2]}[damage]
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(data)
    monkeypatch.setattr(S, "viewer_binary", lambda: pytest.fail("the viewer was started"))
    monkeypatch.setattr(S.shutil, "which", lambda name: f"/usr/bin/{name}")  # as if xvfb-run were there
    with pytest.raises(S.NotARecording, match=rf"{bad} is not a Rerun recording the viewer can show"):
        S.screenshot(bad, tmp_path / "shot.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.rrd", "good.rrd"]


def test_the_cli_refuses_an_unreadable_recording_with_exit_2(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty.rrd").write_bytes(b"")
    assert main(["screenshot", str(tmp_path / "empty.rrd"), "--out", str(tmp_path / "s.png")]) == 2
    assert "empty.rrd is not a Rerun recording" in capsys.readouterr().err
    assert not (tmp_path / "s.png").exists()


@pytest.mark.parametrize("timeout", [0.0, -1.0, float("nan")])
def test_a_timeout_that_is_not_positive_is_refused(tmp_path: Path, timeout: float, recorded: bytes) -> None:
    with pytest.raises(ValueError, match="--timeout must be a positive number of seconds"):
        S.screenshot(_a_recording(tmp_path, recorded), tmp_path / "s.png", timeout_s=timeout)


def _processes_naming(text: str) -> list[str]:
    """Command lines of running (not zombie) processes that contain ``text``."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and (proc / "stat").read_text().split(")")[-1].split()[0] != "Z":
                args = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                found += [args] if text in args else []
        except OSError:
            continue
    return found


@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="needs xvfb-run")
def test_a_timeout_ends_xvfb_and_the_viewer_and_leaves_no_file(tmp_path: Path, recorded: bytes) -> None:
    """F11 (issue 45): a timeout killed xvfb-run only; Xvfb and the viewer went on, and the viewer saved
    NAME.partial.png into the output folder later."""
    rrd = _a_recording(tmp_path, recorded)
    out = tmp_path / "shots"
    out.mkdir()
    with pytest.raises(TimeoutError, match="did not save a screenshot"):
        S.screenshot(rrd, out / "s.png", (1401, 801), timeout_s=0.5)
    screen = "x".join(map(str, S.geometry((1401, 801)).screen))
    assert _processes_naming(str(out / "s.partial.png")) == [] and _processes_naming(screen) == []
    assert list(out.iterdir()) == []
