"""lpv_sysid.control"""
