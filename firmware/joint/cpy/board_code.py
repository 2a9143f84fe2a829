"""Board entry point on CircuitPython: `bioscara flash --runtime circuitpython` copies this file to
CIRCUITPY as /code.py, which CircuitPython runs at boot. It is not part of the `joint` package."""

from joint.cpy import app

app.run()
