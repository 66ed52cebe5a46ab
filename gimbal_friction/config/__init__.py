"""Parameter files: reading and layering YAML, every parameter name of the suite, the node-level settings.

Sits above the features whose settings it layers (feedforward, estimation, sim). May import anything below
chamber; never chamber, runs, nodes or cli.
"""
