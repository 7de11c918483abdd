"""``python -m pointtraj``: the same as the ``pointtraj`` command."""

from .cli import main

if __name__ == "__main__":
    main()
