"""odomgym: wheel-odometry (dead-reckoning) research on a pymunk differential-drive simulator."""
