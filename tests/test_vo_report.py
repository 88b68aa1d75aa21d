"""The vo report's comparison with ORCA (``swarm_env_agents.vo_paper.orca_section``) from made-up results."""

from __future__ import annotations

from typing import Any

import pytest

pytest.importorskip("matplotlib")

from swarm_env_agents.vo_paper import ORCA_SCENARIOS, orca_section  # noqa: E402


def _episode(error: float, success: bool = True, collisions: int = 0, ms: float = 0.1) -> dict[str, Any]:
    return {"success": success, "collisions": {"total": collisions}, "formation_error": {"mean": error},
            "settle_times": [{"hold_fraction": 0.5}], "policy_stats": {"decision_time_ms": {"median": ms}}}


def _row(error: float, success: bool = True) -> dict[str, Any]:
    return {"seed": 0, "success": success, "collisions": {"total": 0}, "formation_error": error,
            "hold_fraction": [0.9], "policy_stats": {"decision_time_ms": {"median": 0.2}}}


def test_every_fixed_scenario_gets_three_rows_and_the_verdict_names_the_losses() -> None:
    reference = {name: {"vo": _episode(0.1), "legacy": _episode(0.3), "orca": _episode(0.2)} for name in ORCA_SCENARIOS}
    reference["corridor"]["vo"] = _episode(0.25)  # vo loses there
    reference["paper_vo_0"]["orca"] = _episode(3.0, success=False)  # orca does not finish: not compared
    results = {"reference": reference, "random": {"episodes": [_row(0.2), _row(0.3), _row(0.4, success=False)]},
               "orca_random": [_row(0.25), _row(0.35), _row(0.1)], "legacy_random": [_row(0.3), _row(0.4), _row(0.5, success=False)]}
    text = "\n".join(orca_section(results))
    for name in ORCA_SCENARIOS:
        assert text.count(f"| {name} |") == 3
    verdict = next(line for line in text.splitlines() if line.startswith("Where both finish"))
    assert "**not** corridor (0.2500 vs 0.2000 m)" in verdict and "paper_vo_0" not in verdict
    assert "paper_vo_90 (0.1000 vs 0.2000 m)" in verdict
    # paired over the two random episodes both finished: vo - orca = -0.05 each; the earlier expert +0.05
    assert "-0.050 ± 0.000 m over the 2 episodes both finished" in text
    assert "earlier `vo` − `orca`: +0.050 ± 0.000 m over the 2 episodes" in text


def test_no_reference_runs_no_section() -> None:
    assert orca_section({"paper": {}, "random": None}) == []
