"""`record` node (not implemented yet)."""


def main(args=None):
    raise SystemExit('record: not implemented yet')
