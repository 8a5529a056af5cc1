"""Application drivers (paper §7): each builds a scene or system from its own inputs, drives the shared stepper
(:func:`idp.stepper.run.run_simulation`) and writes the shared outputs. None owns a Newton loop, a certificate
or a writer."""
