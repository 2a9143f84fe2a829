"""Board manifests: one module per board saying which firmware files that board gets.

The host reads them (`bioscara.flash.board_files`); they are never deployed. A manifest holds two
constants: MAIN, the file copied to the board root as /main.py, and FILES, paths under the `joint`
package, where "pkg/" stands for every module directly in that package. Simulator code (sim/)
never appears in one (tests/test_flash.py checks it). Adding a board is adding one module here.
Imports nothing.
"""
