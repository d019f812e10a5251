"""`herd-ros report` (not implemented yet)."""
HELP = 'not implemented yet'


def add_arguments(parser):
    pass


def run(args):
    raise SystemExit('herd-ros: this verb is not implemented yet')
