"""lpv_sysid.synthesis"""
