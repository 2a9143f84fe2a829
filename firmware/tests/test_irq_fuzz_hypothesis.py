"""Property-based fuzzing of the IRQ path (CPython only: hypothesis does not run on MicroPython)."""

from hypothesis import given, settings, strategies as st

from joint.spec import protocol as P
from harness import Rig

frames = st.one_of(
    st.binary(max_size=12),
    st.builds(lambda r, p: bytes([r]) + p, st.sampled_from([r.addr for r in P.REGISTERS]), st.binary(max_size=6)),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.one_of(st.none(), frames), st.integers(0, 11)), max_size=12))
def test_no_frame_sequence_breaks_the_irq_path(transactions):
    rig = Rig(boot=False)
    rig.run_ms(2000)
    rig.motor.calls = []
    for data, read_len in transactions:
        reply = rig.xfer(data, read_len)
        assert len(reply) == read_len
        rig.run_ms(1)
        rig.assert_handler_alive()
        if data and P.BY_ADDR[data[0]] is None and read_len:
            assert reply[-1] & P.FLAG_ERROR or read_len > 1


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([r for r in P.REGISTERS if r.writable]), st.binary(min_size=0, max_size=8))
def test_invalid_payloads_never_move_the_motor(reg, payload):
    rig = Rig()
    if reg.check_write(payload, 0, len(payload)) == P.REJECT_NONE:
        return
    flags = rig.xfer(bytes([reg.addr]) + payload, 1)[0]
    rig.run_ms(1)
    if not (len(payload) == 0 and reg.readable):
        assert flags & P.FLAG_ERROR
        assert rig.motor.calls == []
