"""Path search: goal configurations, the straight-line approach, transit postures and the OMPL adapter."""
