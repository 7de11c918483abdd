"""Builders the test modules share: camera rigs (:mod:`helpers.rigs`), rendered scenes
(:mod:`helpers.scenes`) and pipeline files (:mod:`helpers.pipelines`).

``tests/`` is on ``sys.path`` (pytest's default ``prepend`` import mode puts the folder of
``tests/conftest.py`` there), so test modules import them as ``helpers.*``; test modules and
conftest files import nothing from one another."""
