// uStepper S32: STM32F401RCT6 (256 KB flash, 64 KB RAM), TMC5130 on SPI2, TLE5012B on SPI3 (SSC),
// the joint bus on I2C1. Pins from uStepper's Arduino variant and library (docs/s32.md).
#define MICROPY_HW_BOARD_NAME       "uStepper S32"
#define MICROPY_HW_MCU_NAME         "STM32F401xC"

// Flash is the budget: the core feature level, plus what the joint firmware and the REPL use:
// machine (I2CTarget, SPI, Pin, mem32), micropython (const, viper: the Thumb emitter stays on
// because frozen viper/native code needs it), memoryview and buffer slice assignment (the IRQ
// path and v2), json (the configuration), time, struct, array. No binascii (its crc32 needs the
// deflate module; protocol.py has its own), no unicode checks, no debug console (select, stdin).
#ifndef MICROPY_CONFIG_ROM_LEVEL
#define MICROPY_CONFIG_ROM_LEVEL    (MICROPY_CONFIG_ROM_LEVEL_CORE_FEATURES)
#endif
#define MICROPY_PY_TIME             (1)
#define MICROPY_HELPER_REPL         (1)
#define MICROPY_KBD_EXCEPTION       (1)
#define MICROPY_STACK_CHECK         (1)
#define MICROPY_ENABLE_FINALISER    (1)
#define MICROPY_ENABLE_SCHEDULER    (1)
#define MICROPY_MODULE_BUILTIN_INIT (1)
#define MICROPY_PY_BUILTINS_MEMORYVIEW (1)
#define MICROPY_PY_ARRAY_SLICE_ASSIGN (1)
#define MICROPY_PY_JSON             (1)
#define MICROPY_PY_OS               (1)  // the port's REPL streams go through os.dupterm's hooks
// Terse errors from the C core (exception types without their messages): 4 KB of flash the
// frozen firmware needs; the firmware's own messages (config, log lines) are unchanged.
#define MICROPY_ERROR_REPORTING     (MICROPY_ERROR_REPORTING_TERSE)
#define MICROPY_EMIT_INLINE_THUMB   (0)
#define MICROPY_OPT_COMPUTED_GOTO   (0)
#define MICROPY_PY_BUILTINS_COMPLEX (0)
#define MICROPY_PY_PYB              (0)
#define MICROPY_PY_PYB_LEGACY       (0)
#define MICROPY_PY_STM              (0)
#define MICROPY_PY_HEAPQ            (0)
#define MICROPY_PY_FRAMEBUF         (0)
#define MICROPY_PY_SOCKET           (0)
#define MICROPY_PY_NETWORK          (0)
#define MICROPY_PY_MACHINE_BITSTREAM (0)
#define MICROPY_PY_ONEWIRE          (0)
// The machine module with only what the joint uses (the port's own list, which this definition
// replaces, adds ADC, PWM, I2S, WDT, pulses and the DHT helper). The joint bus is an I2C target, the
// sensors and the driver are on SPI, the REPL and the log on a UART; the port's I2C and SPI code
// needs its soft I2C and SPI.
#define MICROPY_PY_MACHINE          (1)
#define MICROPY_PY_MACHINE_INCLUDEFILE "ports/stm32/modmachine.c"
#define MICROPY_PY_MACHINE_RESET    (1)
#define MICROPY_PY_MACHINE_BARE_METAL_FUNCS (1)
#define MICROPY_PY_MACHINE_FREQ_NUM_ARGS_MAX (4)
#define MICROPY_PY_MACHINE_BOOTLOADER (1)
#define MICROPY_PY_MACHINE_PIN_MAKE_NEW mp_pin_make_new
#define MICROPY_PY_MACHINE_I2C      (MICROPY_HW_ENABLE_HW_I2C)
#define MICROPY_PY_MACHINE_SOFTI2C  (1)
#define MICROPY_PY_MACHINE_I2C_TARGET (MICROPY_HW_ENABLE_HW_I2C_TARGET)
#define MICROPY_PY_MACHINE_I2C_TARGET_INCLUDEFILE "ports/stm32/machine_i2c_target.c"
#define MICROPY_PY_MACHINE_I2C_TARGET_MAX (4)
#define MICROPY_PY_MACHINE_I2C_TARGET_HARD_IRQ (1)
#define MICROPY_PY_MACHINE_SPI      (1)
#define MICROPY_PY_MACHINE_SPI_MSB  (SPI_FIRSTBIT_MSB)
#define MICROPY_PY_MACHINE_SPI_LSB  (SPI_FIRSTBIT_LSB)
#define MICROPY_PY_MACHINE_SOFTSPI  (1)
#define MICROPY_PY_MACHINE_TIMER    (1)  // the port's machine module names it unconditionally
#define MICROPY_PY_MACHINE_UART     (1)
#define MICROPY_PY_MACHINE_UART_INCLUDEFILE "ports/stm32/machine_uart.c"
#define MICROPY_PY_MACHINE_UART_IRQ (1)
#define MICROPY_PY_MACHINE_UART_READCHAR_WRITECHAR (1)
#define MICROPY_PY_MACHINE_UART_SENDBREAK (1)
#define MICROPY_HW_ENABLE_INTERNAL_FLASH_STORAGE (0)
#define MICROPY_HW_HAS_FLASH        (0)
#define MICROPY_HW_HAS_SWITCH       (0)
#define MICROPY_HW_ENABLE_RTC       (0)
#define MICROPY_HW_ENABLE_RNG       (0)
#define MICROPY_HW_ENABLE_ADC       (0)
#define MICROPY_HW_ENABLE_DAC       (0)
#define MICROPY_HW_ENABLE_SERVO     (0)
#define MICROPY_HW_ENABLE_USB       (0)

// Clock: 20 MHz crystal, PLL M=10 N=168 P=4 -> 84 MHz (APB1 42 MHz), Q=7 -> 48 MHz.
#define MICROPY_HW_CLK_PLLM         (10)
#define MICROPY_HW_CLK_PLLN         (168)
#define MICROPY_HW_CLK_PLLP         (RCC_PLLP_DIV4)
#define MICROPY_HW_CLK_PLLQ         (7)
#define MICROPY_HW_FLASH_LATENCY    (FLASH_LATENCY_2)

// The TMC5130 runs from HSE/2 = 10 MHz on MCO1 (PA8), as the uStepper library's DRIVERCLOCKFREQ
// assumes; board_init.c starts it before anything talks to the driver.
#define MICROPY_BOARD_EARLY_INIT    ustepper_s32_board_early_init
void ustepper_s32_board_early_init(void);

// REPL and debug console on UART2 (PA2 TX, PA3 RX).
#define MICROPY_HW_UART2_TX         (pin_A2)
#define MICROPY_HW_UART2_RX         (pin_A3)
#define MICROPY_HW_UART_REPL        PYB_UART_2
#define MICROPY_HW_UART_REPL_BAUD   115200

// I2C1 is the joint bus (target). I2C2 (PB10 SCL, PB3 SDA) is broken out but the joint does not
// use it: left out, its driver and interrupt handlers would take flash.
#define MICROPY_HW_I2C1_SCL         (pin_B8)
#define MICROPY_HW_I2C1_SDA         (pin_B9)

// SPI2: the TMC5130 (chip select PB12, driven by the firmware). SPI3: the TLE5012B's SSC, whose
// single data line reaches MOSI (PC12) and MISO (PC11); the firmware releases MOSI while reading.
#define MICROPY_HW_SPI2_SCK         (pin_B13)
#define MICROPY_HW_SPI2_MISO        (pin_B14)
#define MICROPY_HW_SPI2_MOSI        (pin_B15)
#define MICROPY_HW_SPI3_SCK         (pin_C10)
#define MICROPY_HW_SPI3_MISO        (pin_C11)
#define MICROPY_HW_SPI3_MOSI        (pin_C12)

// LED on PC13 (active low; not checked on a board).
#define MICROPY_HW_LED1             (pin_C13)
#define MICROPY_HW_LED_ON(pin)      (mp_hal_pin_low(pin))
#define MICROPY_HW_LED_OFF(pin)     (mp_hal_pin_high(pin))
