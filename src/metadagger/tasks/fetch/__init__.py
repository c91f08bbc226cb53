"""FetchPickAndPlace from pixels: the env, its scripted expert and the task."""
