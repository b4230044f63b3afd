"""The belt found from a family line's bare capture, against the belt it was drawn with
(`python -m tofcut.tools.evaluation.belt_check`), and `tofcut record --bare` keeping no belt."""

from __future__ import annotations

from tofcut.driver.capture import CAMERA_KEYS, CaptureReader
from tofcut.tools.cli import main
from tofcut.tools.evaluation import belt_check


def test_the_belt_of_a_bare_family_line_is_found_within_the_bars(tmp_path, capsys):
    folder = tmp_path / "family-conveyor"
    capture = folder / "seed-0" / "capture.tofcap"
    capture.parent.mkdir(parents=True)
    assert main(["record", "emulator:family:conveyor:0", "--bare", "--fast", "--frames", "150",
                 "--seed", "0", "-o", str(capture)]) == 0  # fmt: skip
    assert "not kept: --bare records the camera's stream alone" in capsys.readouterr().out
    assert set(CaptureReader(capture).capture.metadata) == set(CAMERA_KEYS)
    assert belt_check.main([str(folder), "--seconds", "5"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("1 lines; travel: found 1")
    for bar in ("normal within 1 °", "plane within 10 mm", "direction within 2 °",
                "speed within 3 %"):  # fmt: skip
        assert f"- {bar}: 1 of 1 lines\n" in out, out


def test_a_folder_that_is_not_a_familys_is_one_line(tmp_path, capsys):
    assert belt_check.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "is not a family's folder" in err
