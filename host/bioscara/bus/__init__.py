"""The bus interface (`base.Bus`: transactions with retries and link statistics) and the
transports that implement it for I2C hardware: smbus2, Adafruit Blinka, the HIL bridge's serial
link, and simulated joints in this process. Opening one by URL is `transports.open_bus`.

May import `errors`, `paths`, `transmission`, the shared protocol spec and the firmware's simulator
(`firmware.spec`, `firmware.sim`), never the layers
above it (joint, arm, the simulator's service).
"""

from .base import Bus, BusStats, LinkStats

__all__ = ["Bus", "BusStats", "LinkStats"]
