"""What `make docs` generates from the project itself, so the documentation cannot drift from it.

`hooks.py` is the MkDocs hook (mkdocs.yml): a page asks for a generated section with a marker
`<!-- generated: NAME -->` on a line of its own, and pictures are added to the site as generated
files (never committed). The generators read the code they describe: the CLI's argparse parser
(`cli_reference`), the protocol spec (`protocol_reference`), the error tables (`errors_reference`),
the simulated arm (`pictures.homing_trace`). They may import `bioscara`, the firmware's spec through
`bioscara.firmware`, matplotlib and mkdocs; nothing imports them but the hook and the tests.
"""
