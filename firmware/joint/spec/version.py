"""Firmware release, reported through the IDENTITY register."""

FIRMWARE_VERSION = (0, 1, 0)
