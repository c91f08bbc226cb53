"""CarRacing: the fast env (upstream physics, our renderer), its PID expert and the task."""
