"""The declarations every configuration is checked against (no flight logic here).

* :mod:`~lpv_sysid.configuration.fields`: one declaration per configuration key (type, range,
  default, doc) and the validator of YAML mappings against it;
* :mod:`~lpv_sysid.configuration.parameters`: one declaration per node parameter (the same for
  ROS 2 parameters, the parameter files and ``lpv-sysid replay``);
* :mod:`~lpv_sysid.configuration.defaults`: where the shipped configuration files are.

May import: :mod:`lpv_sysid.errors`, :mod:`lpv_sysid.io.files`.
"""
