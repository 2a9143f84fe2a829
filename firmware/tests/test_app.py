"""Boot on the board (app.py) with a stand-in `machine`: bad configurations never crash the firmware."""

from joint import app, startup
from joint.spec import protocol as P
from joint.sim.clock import VirtualClock
from joint.sim.i2c_target import FakeI2CTarget

PATH = "/tmp/bioscara_app_test_config.json"


class Machine:
    """The parts of `machine` app.py uses; `fail` makes I2CTarget refuse its pins."""

    def __init__(self, fail=None):
        self.fail = fail
        self.targets = []

    def disable_irq(self):
        return 0

    def enable_irq(self, state):
        pass

    def Pin(self, number):
        return number

    def I2CTarget(self, bus, addr, scl=None, sda=None, mem=None, mem_addrsize=8):
        if self.fail is not None:
            raise self.fail
        target = FakeI2CTarget(addr, mem=mem, mem_addrsize=mem_addrsize)
        self.targets.append((bus, addr, scl, sda, target))
        return target


def _boot(text, machine):
    with open(PATH, "w") as f:
        f.write(text)
    lines = []
    core, cfg, log = startup.build(machine, PATH, VirtualClock(), lines.append)
    return core, cfg, log, lines


def test_an_invalid_config_starts_disabled_on_the_bus_and_says_why():
    machine = Machine()
    core, cfg, log, lines = _boot('{"joint": "J2", "address": 18, "stall": {"gain": -1}}', machine)
    assert core.disabled and core.ready
    assert any("stall.gain = -1 is out of range" in line for line in lines), lines
    switch = app.join_bus(machine, core, cfg, log)
    assert switch is not None
    assert machine.targets[0][4].transfer(bytes([P.PING]), 2) == b"O\x0c", "answers, disabled"


def test_a_board_motor_backend_that_cannot_start_disables_the_joint():
    core, cfg, log, lines = _boot('{"joint": "J1", "address": 17, "motor": {"backend": "sim"}}', Machine())
    assert core.disabled
    assert any("motor backend failed to start" in line and "cannot run on a board" in line for line in lines)


def test_bus_pins_the_port_refuses_are_reported_not_fatal():
    machine = Machine(fail=ValueError("bad SCL pin"))
    core, cfg, log, lines = _boot('{"joint": "J3", "address": 19}', machine)
    assert app.join_bus(machine, core, cfg, log) is None
    assert any("cannot join the bus" in line and "bad SCL pin" in line for line in lines), lines


def test_pico_joint_bus_pins_are_checked_in_the_config():
    from joint.config import schema as config
    cfg = config.parse({"joint": "J1", "address": 17, "i2c": {"sda": 5, "scl": 4},
                        "motor": {"backend": "pico"}}, "j.json")
    assert "j.json: i2c.sda = 5 is not an SDA pin of I2C0 on the Pico" in cfg.errors
    assert "j.json: i2c.scl = 4 is not an SCL pin of I2C0 on the Pico" in cfg.errors
    assert config.load("firmware/joint/config/J1.json").valid


def test_no_address_means_not_joining_the_bus():
    machine = Machine()
    core, cfg, log, lines = _boot('{"joint": "J1"}', machine)
    assert app.join_bus(machine, core, cfg, log) is None and machine.targets == []
    assert any("no valid I2C address" in line for line in lines)


def test_every_unreadable_config_file_boots_a_disabled_joint_that_says_why():
    bad = ((b'{"joint": "J1\xff\xfe", "address": 17}', "not UTF-8 text"),
           (b"[" * 5000 + b"]" * 5000, "JSON"),  # CPython: too deep; MicroPython: not an object
           (b'{"joint": "J1", "address": 17', "not valid JSON"),
           (b'{"address": 1e999}', "missing required key joint"),
           (b"", "not valid JSON"))
    for raw, why in bad:
        with open(PATH, "wb") as f:
            f.write(raw)
        lines = []
        core, cfg, log = startup.build(Machine(), PATH, VirtualClock(), lines.append)
        assert core.disabled and not cfg.valid, why
        assert any(why in line for line in lines), (why, lines)
        assert any("joint disabled" in line for line in lines), lines
