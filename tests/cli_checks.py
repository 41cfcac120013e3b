"""What the CLI's tests share: a bad call's one-line error."""
from lidar_mitsuba.cli import main


def bad_call(argv, capsys):
    """Run the CLI with ``argv``; assert it exits 2 with one line on stderr and no traceback,
    and return that line."""
    try:
        code = main(argv)
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err
