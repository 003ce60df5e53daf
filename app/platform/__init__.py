"""The service's platform: settings, the database and its models, content-addressed blobs,
authentication, ownership of a data directory, problem details, array files, lookups."""
