"""``python -m clholo``: the ``clholo`` command line where the console script is not on
``PATH`` (a virtual environment not activated, a notebook's ``!python -m clholo info``).

The same entry point as the console script (:func:`clholo_entry.main`): the same exit codes
(``docs/errors.md``) and signal handling, once the package has loaded.
"""

import sys

from clholo_entry import main

if __name__ == "__main__":
    sys.exit(main())
