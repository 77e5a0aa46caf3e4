"""``python -m skyfix …``: the ``skyfix`` command without its console script."""

from skyfix.cli import main

if __name__ == "__main__":
    main()
