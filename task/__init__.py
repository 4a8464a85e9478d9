"""The task: the operator's command (its fields, postures, the command filter), the scripted schedules, tracking, and
the hand-over rule a teacher runs and its students compute."""
