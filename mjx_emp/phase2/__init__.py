"""Phase 2: a goal-reaching policy over a trained run's frozen skills (the paper's downstream task)."""
