"""Board entry point: MicroPython runs this file at boot."""

from joint import app

app.run()
