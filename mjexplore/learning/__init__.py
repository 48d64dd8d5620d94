"""Learning: PPO training of the policies (one machine or a Ray cluster), imitation of the
oracle, the pocket predictor's training, and the rollout machinery they share."""
