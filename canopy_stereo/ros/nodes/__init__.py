"""The ROS 2 nodes: thin shells that convert messages, hold parameters and call the core.

=================  =============================  ==================================
executable         subscribes (namespace /stereo)  publishes
=================  =============================  ==================================
camera_node        -                               ``<camera_name>/image_raw``
rectify_node       ``left|right/image_raw``        ``left|right/image_rect``,
                                                   ``left/image_rect_color``,
                                                   ``left|right/camera_info``
disparity_node     ``left|right/image_rect``       ``disparity``
segment_node       ``left/image_rect_color``       ``left/mask``
point_cloud_node   ``disparity``,                  ``points2``
                   ``left/image_rect_color``,
                   ``left/mask`` (``use_mask``)
=================  =============================  ==================================
"""
