"""`bioscara panel`: the arm's control panel in a terminal (Textual) and in a browser.

`model.py` holds what the panel shows and does (no Textual), `app.py` its screen, `terminal.py` the
driver that lets it end when its terminal goes away, `screenshot.py` the documentation's picture.
May import the rest of the host package (arm, communicator, config); `commands/panel.py` starts it.
"""
