"""The firmware is one set of modules in the tests: `joint.X` and `bioscara.firmware.X` are the same objects."""

import importlib

import pytest


@pytest.mark.parametrize("name", ["spec.protocol", "spec.protocol_v2", "core.controller", "links.memmap_v2",
                                  "config.schema", "sim.joint"])
def test_joint_and_bioscara_firmware_name_one_module(name):
    assert importlib.import_module("joint." + name) is importlib.import_module("bioscara.firmware." + name)


def test_the_host_and_the_firmware_share_one_register_class():
    from joint.spec import protocol as firmware_side
    from bioscara import joint as host_joint
    from bioscara.firmware.spec import protocol as host_side

    assert firmware_side.Register is host_side.Register
    assert host_joint.P is host_side
    assert isinstance(firmware_side.REGISTERS[0], host_side.Register)
