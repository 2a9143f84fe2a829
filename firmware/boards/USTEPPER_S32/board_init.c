// uStepper S32 early init: the TMC5130's 10 MHz clock (HSE / 2) on MCO1. The HAL call also puts
// PA8 in its MCO alternate function.
#include "py/mphal.h"

void ustepper_s32_board_early_init(void) {
    HAL_RCC_MCOConfig(RCC_MCO1, RCC_MCO1SOURCE_HSE, RCC_MCODIV_2);
}
