"""Offline tools behind the ``gimbal-friction`` command line (argparse layer + commands; no physics here)."""
