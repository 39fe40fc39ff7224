"""The ``jcalib`` command and the demos: parse arguments, call one function, print; wires the simulators."""
