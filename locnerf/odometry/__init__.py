"""Real odometry: OpenCV RGB-D odometry of camera frames, and recorded trajectories on a run's stamps."""
