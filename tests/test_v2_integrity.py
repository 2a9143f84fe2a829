"""Protocol v2 under attack (a few thousand corrupted frames each way; `make bench` runs 100,000)."""

from __future__ import annotations

import v2_attack


def test_corrupted_commands_are_never_applied_and_always_counted() -> None:
    result = v2_attack.attack_joint(2000, seed=11)
    assert all(count > 300 for count in result.by_kind.values()), result.by_kind
    assert result.applied == 0 and result.uncounted == 0 and result.intact_lost == 0, result


def test_corrupted_states_are_never_taken_and_always_counted() -> None:
    result = v2_attack.attack_host(2000, seed=12)
    assert all(count > 300 for count in result.by_kind.values()), result.by_kind
    assert result.accepted_wrong == 0 and result.uncounted == 0 and result.intact_lost == 0, result


def test_crc8_catches_every_error_of_up_to_three_bits_in_both_blocks() -> None:
    assert v2_attack.check_crc_catches_every_error_of_up_to_3_bits() > 50_000


def test_the_chip_comparison_vectors_are_deterministic_and_cover_each_verdict() -> None:
    import v2_vectors
    from bioscara.firmware.spec import protocol_v2 as V
    vectors = v2_vectors.sim_vectors()
    again = v2_vectors.sim_vectors()
    assert v2_vectors.compare(vectors, [v.reply for v in again]) == []
    states = [V.decode_state(0x11, v.reply) for v in vectors if v.read_len == V.STATE_SIZE]
    verdicts = {s[1] for s in states[1:] if s is not None}
    assert {V.REASON_OK, V.REASON_CRC, V.REASON_SEQUENCE, V.REASON_FRAME} <= verdicts, verdicts
    assert vectors[-1].reply == b"O" + bytes([vectors[-1].reply[1]]), "legacy again at the end"
