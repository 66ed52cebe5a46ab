"""The gimbal-friction command line: each subcommand parses its arguments, calls one library function, maps errors.

Thin by rule: no model logic here. May import every library folder; nothing imports cli.
"""
