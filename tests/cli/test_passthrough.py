"""Benchmark commands pass their words on unparsed (``margcal diagnose-benchmark --quick`` was refused: an argparse
REMAINDER takes nothing when its first word is an option)."""

from __future__ import annotations

import pytest

from ros_margcal.cli import _passthrough, main


@pytest.mark.parametrize(("words", "own", "passed"), [
    (["diagnose-benchmark", "--quick", "--part", "rough"], ["diagnose-benchmark"], ["--quick", "--part", "rough"]),
    (["-v", "bench", "fitting", "--quick"], ["-v", "bench", "fitting"], ["--quick"]),
    (["bench", "diagnosis"], ["bench", "diagnosis"], []),
    (["replay", "--example"], ["replay", "--example"], None),
    (["bench", "--help"], ["bench", "--help"], None),
])
def test_the_words_are_split_where_the_benchmark_begins(words: list[str], own: list[str], passed: list[str] | None) -> None:
    assert _passthrough(words) == (own, passed)


def test_diagnose_benchmark_hands_its_options_to_the_benchmark(capsys: pytest.CaptureFixture[str]) -> None:
    """An option the benchmark does not know is refused by the benchmark's own parser (its usage line), not by
    margcal's ("unrecognized arguments" before the benchmark ever saw it)."""
    with pytest.raises(SystemExit) as exc:
        main(["diagnose-benchmark", "--no-such-option"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "margcal bench diagnosis" in err and "--no-such-option" in err, err
