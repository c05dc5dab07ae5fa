"""Runs: the one place that builds, resumes, checkpoints, saves and evaluates a training run (rl-baselines3-zoo's
``ExperimentManager`` role), used by ``train``, ``train --seeds`` and every sweep trial."""
