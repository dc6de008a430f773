"""python -m imm_gym.track at its edges, each against a value worked by hand."""

from __future__ import annotations

from imm_gym.cli.track import tpm_columns


def test_tpm_columns_of_ten_models_are_digits_and_of_eleven_separated() -> None:
    """Ten models name entry (i, j) tpm{i}{j} without ambiguity (one digit each); from eleven
    on, tpm{i}_{j}."""
    ten = tpm_columns(10)
    assert ten[:3] == ["tpm00", "tpm01", "tpm02"] and ten[-1] == "tpm99" and len(set(ten)) == 100
    eleven = tpm_columns(11)
    assert eleven[:2] == ["tpm0_0", "tpm0_1"] and eleven[-1] == "tpm10_10"
