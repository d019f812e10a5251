"""`estimator` node (not implemented yet)."""


def main(args=None):
    raise SystemExit('estimator: not implemented yet')
