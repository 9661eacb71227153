"""Aid sources: one module per sensor model, in the style of PX4 EKF2's aid_sources/.

Each module holds its measurement prediction h(x) and Jacobian, its noise, its gate and
test ratio, its preprocessing and its innovation key, as compiled functions over the core's
state records (windahrs.core). The sensor registry is :data:`windahrs.core.layout.AID_LOGS`.

==================  ===================================================  ============
module              measurement                                          innovation
==================  ===================================================  ============
``gravity``         accelerometer as gravity, with its compensations     ``accel``
``mag``             magnetometer, 3-D or heading                         ``mag``
``gnss_vel``        GNSS velocity                                        ``gnss``
``air_vector``      the paper's air-data vector V_T^b                    ``air``
``tas``             true airspeed                                        ``tas``
``sideslip``        synthetic zero sideslip                              ``sideslip``
``aoa``             angle of attack of a vane without a sideslip vane    ``aoa``
``drag``            multirotor drag in the accelerometer's x, y          ``drag``
``airspeed_scale``  the pitot's scale, a small EKF beside the filter    ``aspd`` log
==================  ===================================================  ============
"""
