"""The ROS 2 nodes: thin shells that convert messages, hold parameters and call the core.

=================  ====================================  ==================================
executable         subscribes (namespace /stereo)         publishes
=================  ====================================  ==================================
camera_node        -                                      ``<camera_name>/image_raw``,
                                                          ``<camera_name>/camera_info`` (rig)
rectify_node       ``left|right/image_raw``               ``left|right/image_rect``,
                                                          ``left/image_rect_color``,
                                                          ``left|right/image_rect/camera_info``,
                                                          ``stereo_geometry``, ``/tf_static``
disparity_node     ``left|right/image_rect``,             ``disparity``
                   ``left|right/image_rect/camera_info``
segment_node       ``left/image_rect_color``              ``left/mask``
point_cloud_node   ``disparity``,                         ``points2``, ``left/depth``,
                   ``left/image_rect_color``,             ``left/depth/camera_info``
                   ``left/image_rect/camera_info``,
                   ``stereo_geometry``,
                   ``left/mask`` (``use_mask``)
=================  ====================================  ==================================

Only ``rectify_node`` (and ``camera_node``, as a driver, for its ``camera_info``) read the
rig; the others take the geometry from the messages (:mod:`canopy_stereo.ros.stereo_geometry`).
"""
