"""The motor's contract and integer motion primitives: the HAL every backend implements
(hal.py), fixed-point arithmetic (fixed.py), the per-tick ramp (tickramp.py) and the encoder
velocity estimators (velocity.py). May import micro only."""
