"""Parts and traces as the service keeps them: mesh intake (frame, archive, facts), part
storage, trace records, and the caches built on parts (in memory and on disk)."""
