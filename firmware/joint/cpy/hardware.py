"""CircuitPython objects behind the interfaces pico.motor.PicoStepper drives: the machine.UART,
machine.I2C, rp2.StateMachine and machine.Pin calls it makes, on busio, rp2pio and digitalio.

CircuitPython has no rp2.asm_pio: BURST_PROGRAM is pico.stepgen.burst_program assembled by hand
(RP2040 datasheet 3.4; tests/chip compares it with MicroPython's assembly). Without viper there is
no direct register access, so the stepper uses these objects' methods (pio and encoder registers
0): the AS5600 sample is a blocking read, about 80 us of wire time at 1 MHz. The one register
written directly is the step generator's TX FIFO, through memorymap (StepMachine).
"""

from array import array

from ..micro import const

# pico.stepgen.burst_program: side-set 1 pin, optional (2 bits), 3 delay bits; OUT shifts right.
BURST_PROGRAM = array("H", (
    0x80A0,  # pull block
    0xA0C7,  # mov isr, osr
    0x6001,  # out pins, 1            DIR
    0x602F,  # out x, 15              pulses - 1
    0xBA47,  # pulse: mov y, osr  side 1 [2]
    0x1085,  # low: jmp y--, low  side 0
    0x0044,  # jmp x--, pulse
    0x8020,  # push block             the acknowledgement
))


class UartPort:
    """machine.UART's any/readinto/write on a busio.UART (TMC2209 one-wire: RX sees the echo)."""

    def __init__(self, uart):
        self._uart = uart

    def any(self):
        return self._uart.in_waiting

    def readinto(self, buf):
        return self._uart.readinto(buf)

    def write(self, buf):
        return self._uart.write(buf)


def no_bus():
    """The joint bus's poll when there is none: no request served."""
    return False


class EncoderBus:
    """machine.I2C's memory reads and writes on a locked busio.I2C (the AS5600 is alone on it).
    After each read it calls `serve` (cpy/app.py sets the joint bus's poll): the encoder is
    read early in every iteration, so a host's read is answered mid-iteration, as the hard IRQ
    answers it on MicroPython, instead of waiting for the whole iteration."""

    serve = staticmethod(no_bus)

    def __init__(self, i2c):
        while not i2c.try_lock():
            pass
        self._i2c = i2c
        self._reg = bytearray(1)
        self._write = bytearray(3)

    def readfrom_mem_into(self, address, reg, buf):
        self._reg[0] = reg
        self._i2c.writeto_then_readfrom(address, self._reg, buf)
        self.serve()

    def readfrom_into(self, address, buf):
        self._i2c.readfrom_into(address, buf)
        self.serve()

    def writeto_mem(self, address, reg, buf):
        out = self._write
        out[0] = reg
        for i in range(len(buf)):
            out[i + 1] = buf[i]
        self._i2c.writeto(address, out, end=len(buf) + 1)


class StepMachine:
    """rp2.StateMachine's put/get/rx_fifo on an rp2pio.StateMachine, one 32-bit word at a time.
    `put` stores the word in the state machine's TX FIFO register (`txf`, a memorymap range):
    rp2pio's write() returns only once the FIFO is empty again, which is when the PIO pulls the
    word, at the end of the burst running (about 540 us an iteration while moving, measured);
    the stepper never has more words in flight than the FIFO holds. Then it calls `serve`, as
    EncoderBus does: late in a moving iteration, where the next poll was about 1.8 ms away; and
    at each look at the RX FIFO, which the motor's update starts with (about 0.2 ms into the
    core's iteration, 0.45 ms before the encoder's read: the longest wait for a reply was there)."""

    serve = staticmethod(no_bus)

    def __init__(self, sm, txf):
        self._sm = sm
        self._txf = txf
        self._word = array("L", (0,))
        self._word_bytes = memoryview(self._word).cast("B")  # memorymap takes bytes only

    def put(self, word):
        self._word[0] = word
        self._txf[0:4] = self._word_bytes
        self.serve()

    def get(self):
        self._sm.readinto(self._word)
        return self._word[0]

    def rx_fifo(self):
        self.serve()
        return self._sm.in_waiting


class EnablePin:
    """machine.Pin's value(v) on a digitalio output."""

    def __init__(self, pin):
        self._pin = pin

    def value(self, level):
        self._pin.value = bool(level)


_PIO_BASES = (0x50200000, 0x50300000)  # PIO0, PIO1 (RP2040 datasheet 3.7)
_PIO_CTRL = const(0x000)  # SM_ENABLE in bits 0..3
_PIO_TXF0 = const(0x010)
_PIO_SM0_PINCTRL = const(0x0DC)
_PIO_SM_STRIDE = const(0x18)


def tx_fifo(dir_pin, step_pin):
    """The TX FIFO register, as a 4-byte memorymap.AddressRange, of the running state machine
    whose OUT pins start at `dir_pin` and side-set pins at `step_pin`: rp2pio does not say
    which state machine it claimed."""
    import memorymap

    def word(address):
        return int.from_bytes(memorymap.AddressRange(start=address, length=4)[0:4], "little")

    for base in _PIO_BASES:
        enabled = word(base + _PIO_CTRL)
        for index in range(4):
            pins = word(base + _PIO_SM0_PINCTRL + index * _PIO_SM_STRIDE)
            if enabled >> index & 1 and pins & 0x1F == dir_pin and pins >> 10 & 0x1F == step_pin:
                return memorymap.AddressRange(start=base + _PIO_TXF0 + 4 * index, length=4)
    raise RuntimeError("no running PIO state machine drives DIR GP%d and STEP GP%d" % (dir_pin, step_pin))


_I2C_BASES = (0x40044000, 0x40048000)  # I2C0, I2C1 (RP2040 datasheet 2.2)
_IC_RAW_INTR_STAT = const(0x34)
_IC_RXFLR = const(0x78)
_READING = const(0x20)  # RD_REQ (bit 5), in the register's 1st byte
_WRITE_ENDED = const(0x12)  # RESTART_DET (bit 12) or STOP_DET (bit 9), in the register's 2nd byte


class TargetFifo:
    """What links/cp_target.py needs of the joint bus's I2C block that i2ctarget does not say
    (RP2040 datasheet 4.3): whether the host's write has ended (the host reads, or a repeated
    START or a STOP since it began) and how many bytes it left in the RX FIFO. RD_REQ counts
    first: i2ctarget's request() clears RESTART_DET with the STOP_DET of the transaction before,
    so a request polled late finds the repeated START of its own transaction cleared (every such
    write then waited out the checks and read() without a count: 1.85 ms and more, measured). A request's read() without a count
    returns only after reading the empty FIFO once more, which took about 1 ms on the emulated
    chip; read(n) of what is there, 30-60 us. Each register read makes a 4-byte bytes object."""

    def __init__(self, sda):
        import memorymap

        base = _I2C_BASES[(sda >> 1) & 1]  # GP4/5 I2C0, GP6/7 I2C1, and so on in fours
        self._regs = memorymap.AddressRange(start=base + _IC_RAW_INTR_STAT,
                                            length=_IC_RXFLR + 4 - _IC_RAW_INTR_STAT)

    def write_ended(self):
        raw = self._regs[0:4]
        return raw[0] & _READING or raw[1] & _WRITE_ENDED

    def rx_level(self):
        return self._regs[_IC_RXFLR - _IC_RAW_INTR_STAT:_IC_RXFLR - _IC_RAW_INTR_STAT + 4][0]


def gpio(number):
    import board
    return getattr(board, "GP%d" % number)


def build_stepper(cls, motor_cfg, clock):
    """pico.motor_config.build_stepper's objects, from CircuitPython's modules."""
    import busio
    import digitalio
    import rp2pio

    from ..pico import tmc2209 as tmc
    from ..pico.as5600 import AS5600
    from ..pico.motor_config import resolved
    from ..pico.stepgen import SM_FREQ, StepGenerator

    c = resolved(motor_cfg)
    char_ms = 1 + 10000 // c["uart_baud"]
    uart = busio.UART(gpio(c["uart_tx"]), gpio(c["uart_rx"]), baudrate=c["uart_baud"],
                      timeout=(2 + 3 * char_ms) / 1000, receiver_buffer_size=64)
    i2c = busio.I2C(gpio(c["encoder_scl"]), gpio(c["encoder_sda"]), frequency=c["encoder_freq"])
    enable = digitalio.DigitalInOut(gpio(c["enable"]))
    enable.switch_to_output(value=True)  # ENN high: bridges off until begin()
    sm = rp2pio.StateMachine(BURST_PROGRAM, frequency=SM_FREQ, first_out_pin=gpio(c["dir"]),
                             initial_out_pin_state=0, initial_out_pin_direction=1,
                             first_sideset_pin=gpio(c["step"]), initial_sideset_pin_state=0,
                             initial_sideset_pin_direction=1, sideset_enable=True,
                             out_shift_right=True, wait_for_txstall=False)
    return cls(tmc.TMC2209(UartPort(uart), c["tmc_address"]), AS5600(EncoderBus(i2c)),
               StepGenerator(StepMachine(sm, tx_fifo(c["dir"], c["step"])), c["microsteps"], c["max_step_rate"], SM_FREQ),
               EnablePin(enable), clock,
               c["update_hz"], c["rsense_ohm"], c["full_scale_ma"],
               c["encoder_slow_filter"], c["encoder_fast_threshold"])
