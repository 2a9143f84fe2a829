"""The protocol as the joint keeps it: the legacy register map and frames (protocol.py), the v2
memory map (protocol_v2.py), the firmware version and the boot-built register table (regtable.py).
The host reads the same files as `bioscara.firmware.spec`. Imports only the `micro` shim beside it."""
