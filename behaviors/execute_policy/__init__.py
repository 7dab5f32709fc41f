"""ExecutePolicy: stream a policy's action chunks as one continuous, checked motion."""
