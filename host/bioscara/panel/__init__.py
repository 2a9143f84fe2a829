"""`bioscara panel`: the arm's control panel in a terminal (Textual) and in a browser."""
