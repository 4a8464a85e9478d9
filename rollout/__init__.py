"""Running a controller: the controller interface, building one by name, and the rollout of one episode."""
