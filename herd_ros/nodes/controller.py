"""`controller` node (not implemented yet)."""


def main(args=None):
    raise SystemExit('controller: not implemented yet')
