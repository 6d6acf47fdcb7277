"""Model-based baselines designed from the FMU itself: LQR and MPC controllers.

``linear`` linearises an FMU's model-exchange interface at an operating point (central differences
of the state derivatives and outputs) and samples the model with a zero-order hold; ``riccati``
solves the discrete algebraic Riccati equation; ``design`` makes an LQR design at one operating
point (steady-state targets, feedback, preview feed-forward, a steady-state Kalman filter);
``controller`` runs the LQR (designs blended on a schedule signal) and ``mpc`` the MPC over the
same design with OSQP. Both see the task's named signals in physical units and are baselines like
the PID controller (``type: lqr`` or ``type: mpc`` in an experiment's ``evaluation.baselines``).

Needs the ``control`` extra (scipy, OSQP). May import the experiment, the FMU runtime and the
example models; never the env, the network or recording.
"""
