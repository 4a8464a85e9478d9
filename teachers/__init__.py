"""The teachers: scripted controllers a student learns from, one module each, registered by name
(`teachers.registry`)."""
