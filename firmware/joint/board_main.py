"""Board entry point: `bioscara flash` copies this file to the board root as /main.py,
which MicroPython runs at boot. It is not part of the `joint` package on the board."""

from joint import app

app.run()
