"""Per-joint configuration: the shipped files are valid, bad files give precise messages, never a crash."""

import json

from joint.config import schema as config
from joint.spec import protocol as P
from harness import Rig

CONFIG_DIR = "firmware/joint/config/"


def _sim_version(path):
    with open(path) as f:
        data = json.loads(f.read())
    data["motor"] = {"backend": "sim"}
    return data


def test_shipped_configs_are_valid_and_address_the_right_joint():
    for i, joint in enumerate(config.JOINTS):
        cfg = config.load(CONFIG_DIR + joint + ".json")
        assert cfg.valid, cfg.errors
        assert cfg.joint == joint and cfg.joint_id == i + 1 and cfg.address == 0x11 + i
        assert cfg.stall.window_low == 12.0 and cfg.stall.window_offset == 90.0
        assert cfg.boot.max_acceleration == 100.0 and cfg.boot.max_velocity == 10.0


def test_missing_keys_take_the_original_constants():
    cfg = config.parse({"joint": "J3", "address": 0x13})
    assert cfg.valid, cfg.errors
    assert cfg.deadman_ms == 50 and cfg.stall.time_constant == 0.1 and cfg.boot.control_threshold == 15.0


def _errors(data):
    return config.parse(data, "j.json").errors


def test_each_kind_of_mistake_gets_its_own_message():
    base = {"joint": "J1", "address": 17}
    cases = (
        (dict(base, address=200), "j.json: address = 200 is out of range 8..119"),
        (dict(base, joint="J9"), "j.json: joint = 'J9' is not one of J1, J2, J3, J4"),
        (dict(base, deadman_ms="50"), "j.json: deadman_ms must be an integer, got '50'"),
        (dict(base, stall={"slope": True}), "j.json: stall.slope must be a number, got True"),
        (dict(base, stall={"windowlow": 3}), "j.json: unknown key stall.windowlow"),
        (dict(base, colour="red"), "j.json: unknown key colour"),
        ({"joint": "J1"}, "j.json: missing required key address"),
        (dict(base, stall={"window_low": 500}), "j.json: stall.window_low (500.0) must not exceed stall.window_high (450.0)"),
        (dict(base, boot=3), "j.json: boot must be an object"),
        (dict(base, motor={"backend": "stepper9000"}), "j.json: motor.backend = 'stepper9000' is not one of pico, s32, sim"),
    )
    for data, message in cases:
        errors = _errors(data)
        assert message in errors, (message, errors)


def test_unreadable_and_malformed_files_are_reported():
    cfg = config.load("/nonexistent/joint_config.json")
    assert not cfg.valid and "cannot read the file" in cfg.errors[0]
    path = "/tmp/bioscara_bad_config.json"
    with open(path, "w") as f:
        f.write("{\"joint\": \"J1\", ")
    cfg = config.load(path)
    assert not cfg.valid and "not valid JSON" in cfg.errors[0]


def test_invalid_config_starts_disabled_and_reports_on_the_console():
    cfg = config.parse({"joint": "J2", "address": 0x12, "stall": {"gain": -1}}, "joint_config.json")
    rig = Rig(cfg=cfg, boot=False)
    assert rig.core.ready and rig.core.disabled
    assert any("stall.gain = -1 is out of range" in line for line in rig.lines), rig.lines
    assert any("joint disabled" in line for line in rig.lines)
    assert rig.xfer(bytes([P.PING]), 2) == b"O\x0c", "still answers PING"
    flags = rig.command("SETUP", 20, 20, 0, 0)
    rig.run_ms(5)
    assert flags & P.FLAG_ERROR and flags & P.FLAG_NOTENABLED
    assert rig.read("LASTERROR")[0][0] == P.REJECT_DISABLED
    assert rig.motor.calls == [], "the motor is never touched"
