"""The command lines of the evaluation tools (``poseidon eval``, ``poseidon vpr``): argument parsing and
printing over the computing modules of :mod:`eval`."""
