"""`gps_ingest` node (not implemented yet)."""


def main(args=None):
    raise SystemExit('gps_ingest: not implemented yet')
