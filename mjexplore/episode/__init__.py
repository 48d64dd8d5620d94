"""The episode engine: one exploration episode (sim, lidar, mapping, topology, navigation
and an explorer) stepped in simulated time, and its metrics. Evaluation, the Gymnasium env
and training build on it; it imports nothing above it."""

from mjexplore.episode.engine import END_REASONS, Episode, EpisodeConfig, EpisodeResult, Interrupted
from mjexplore.episode.metrics import MILESTONES, episode_metrics, first_time_at, pose_errors

__all__ = ["END_REASONS", "Episode", "EpisodeConfig", "EpisodeResult", "Interrupted",
           "MILESTONES", "episode_metrics", "first_time_at", "pose_errors"]
