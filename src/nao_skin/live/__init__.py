"""Pure logic behind the live nodes: heat-map counts, playback, reconnection back-off."""
