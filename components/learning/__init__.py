"""Learning beyond the specialists' PPO (paper §"Learning a Generalist from Specialists"): the vision-based
generalist's cameras (:mod:`vision`) and its DAgger distillation (:mod:`dagger`)."""
