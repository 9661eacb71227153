"""Process and measurement models with analytic Jacobians (and numeric twins in the tests).
Models own the math; filters are generic over them."""
