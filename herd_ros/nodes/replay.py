"""`replay` node (not implemented yet)."""


def main(args=None):
    raise SystemExit('replay: not implemented yet')
