"""`fleet_sim` node (not implemented yet)."""


def main(args=None):
    raise SystemExit('fleet_sim: not implemented yet')
