"""Looking at bundles and sessions: the HTML report (report), figures of a session
trace (plot), the texture as sound (sound) and the live 3-D viewer (viewer)."""
