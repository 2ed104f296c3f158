"""lpv_sysid.report"""
