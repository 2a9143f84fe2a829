"""Each context of JointController writes only its own state (core/controller_init.py's tables),
and the state the IRQ context and the main loop share is exactly the list there."""

import ast
import pathlib

import pytest

from joint.core import controller_init as owners

CORE = pathlib.Path(__file__).resolve().parents[1] / "firmware" / "joint" / "core"
CONTEXTS = {"IRQ": ("irq.py",), "MAIN_LOOP": ("loop.py", "handlers.py"), "SUPERVISION": ("supervise.py",),
            "TASKS": ("tasks.py",)}


def _targets(node):
    """The assignment targets of `node`, tuples unpacked."""
    targets = (node.targets if isinstance(node, ast.Assign) else
               [node.target] if isinstance(node, (ast.AugAssign, ast.AnnAssign)) else [])
    while any(isinstance(t, ast.Tuple) for t in targets):
        targets = [e for t in targets for e in (t.elts if isinstance(t, ast.Tuple) else [t])]
    return targets


def _attributes(files):
    """(written, read) attributes of the controller (`self.x`, `core.x`) in `files` (an item
    written into one, `self.x[i] = v`, writes no attribute)."""
    written, read = set(), set()
    for name in files:
        for node in ast.walk(ast.parse((CORE / name).read_text())):
            for target in _targets(node):
                if isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name) and target.value.id in ("self", "core"):
                    written.add(target.attr)
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in ("self", "core"):
                read.add(node.attr)
    return written, read


@pytest.mark.parametrize("context", sorted(CONTEXTS))
def test_a_context_writes_only_its_own_state_or_the_listed_shared_state(context):
    written, _ = _attributes(CONTEXTS[context])
    # flags and halts: written by the IRQ and the main loop alike, inside the critical section
    shared = {"flags", "halts"} if context == "IRQ" else set(owners.MAIN_SHARED)
    allowed = set(getattr(owners, context)) | shared
    assert written <= allowed, f"{context} writes {sorted(written - allowed)}, owned elsewhere"


def test_the_owners_tables_do_not_overlap():
    tables = [set(getattr(owners, name)) for name in ("IRQ", "MAIN_LOOP", "SUPERVISION", "TASKS", "MAIN_SHARED")]
    for i, table in enumerate(tables):
        for other in tables[i + 1:]:
            assert not table & other, sorted(table & other)


def test_the_irq_and_the_main_loop_share_exactly_the_listed_state():
    irq_written, irq_read = _attributes(CONTEXTS["IRQ"])
    main = sum((CONTEXTS[c] for c in ("MAIN_LOOP", "SUPERVISION", "TASKS")), ())
    main_written, main_read = _attributes(main)
    shared = (irq_written & (main_read | main_written)) | (main_written & irq_read)
    assert shared == set(owners.IRQ_SHARED)


def test_every_owned_attribute_is_created_when_the_controller_is_built():
    from harness import Rig

    core = Rig(boot=False).core
    for name in ("IRQ", "MAIN_LOOP", "SUPERVISION", "TASKS", "MAIN_SHARED", "IRQ_SHARED"):
        missing = [attr for attr in getattr(owners, name) if attr not in core.__dict__]
        assert not missing, (name, missing)


def _table_writes(files):
    """Offsets of the frame table's bytes written in `files`: `self._ftab[X]`, `ftab[X]` (its
    alias in the main loop) or `t[X]` (its pointer in the viper judge), X an offset constant of
    the module, possibly plus a number."""
    import importlib

    offsets = set()
    for name in files:
        module = importlib.import_module("joint.core." + name[:-3])
        for node in ast.walk(ast.parse((CORE / name).read_text())):
            for target in _targets(node):
                if not isinstance(target, ast.Subscript):
                    continue
                table = target.value
                if not (isinstance(table, ast.Name) and table.id in ("ftab", "t")
                        or isinstance(table, ast.Attribute) and table.attr == "_ftab"):
                    continue
                index = target.slice.left if isinstance(target.slice, ast.BinOp) else target.slice
                offset = getattr(module, index.id)
                if isinstance(target.slice, ast.BinOp):
                    offset += target.slice.right.value
                offsets.add(offset)
    return offsets


def _table_offsets(names):
    from joint.core import irq_init as T

    offsets = set()
    for name in names:
        start = getattr(T, name)
        # LASTERROR's record: reason, register, count (its last byte, the flags, is the reply path's)
        offsets |= set(range(start, T.Q_IN - 1)) if name == "LASTERROR_WIRE" else {start}
    return offsets


def test_each_context_writes_only_its_bytes_of_the_frame_table():
    assert _table_writes(CONTEXTS["IRQ"]) == _table_offsets(owners.TABLE_IRQ)
    main = sum((CONTEXTS[c] for c in ("MAIN_LOOP", "SUPERVISION", "TASKS")), ())
    assert _table_writes(main) == _table_offsets(owners.TABLE_MAIN)
