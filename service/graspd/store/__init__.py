"""graspd.store: persistence behind one SQLAlchemy URL: the template library's tables, grasp outcomes, instance
model names.  Imports only graspd.core."""
