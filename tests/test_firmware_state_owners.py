"""Each context of JointController writes only its own state (core/controller_init.py's tables),
and the state the IRQ context and the main loop share is exactly the list there."""

import ast
import pathlib

import pytest

from joint.core import controller_init as owners

CORE = pathlib.Path(__file__).resolve().parents[1] / "firmware" / "joint" / "core"
CONTEXTS = {"IRQ": ("irq.py",), "MAIN_LOOP": ("loop.py", "handlers.py"), "SUPERVISION": ("supervise.py",),
            "TASKS": ("tasks.py",)}


def _attributes(files):
    """(written, read) attributes of the controller (`self.x`, `core.x`) in `files`."""
    written, read = set(), set()
    for name in files:
        for node in ast.walk(ast.parse((CORE / name).read_text())):
            targets = (node.targets if isinstance(node, ast.Assign) else
                       [node.target] if isinstance(node, (ast.AugAssign, ast.AnnAssign)) else [])
            for target in targets:
                for sub in ast.walk(target):
                    if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name) and sub.value.id in ("self", "core"):
                        written.add(sub.attr)
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
