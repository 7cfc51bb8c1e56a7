%% @doc Internal. Application callback: reads the node configuration file
%% (node_config:file/0) and fills the other applications' environment
%% before they start, or stops the node's start with the file's mistakes.
-module(node_config_app).
-behaviour(application).

-include_lib("kernel/include/logger.hrl").

-export([start/2, stop/1]).

-spec start(application:start_type(), term()) -> {ok, pid()} | {error, term()}.
start(_Type, _Args) ->
    case node_config:file() of
        none ->
            ?LOG_NOTICE(#{what => no_node_config,
                          message => <<"no configuration file (EVATAR_CONFIG unset, no etc/evatar.config)">>}),
            node_config_sup:start_link();
        {_, File} ->
            case node_config:load(File) of
                {ok, Config} ->
                    ok = node_config:apply_env(Config),
                    ?LOG_NOTICE(#{what => node_config_loaded, file => File,
                                  listeners => listeners(Config),
                                  pairings => [Id || #{id := Id} <- maps:get(pairings, Config)],
                                  mqtt_avatars => [Id || #{entity_id := Id}
                                                             <- maps:get(mqtt_avatars, Config)]}),
                    node_config_sup:start_link();
                {error, Reason} ->
                    %% Said on the console too: a node started by
                    %% `bin/evatar foreground' or a service manager shows
                    %% it there, before the boot's own crash report.
                    Text = node_config:format_error(Reason),
                    io:put_chars(standard_error, ["EVATAR will not start: the configuration file has "
                                                  "mistakes\n", Text]),
                    ?LOG_ERROR(#{what => bad_node_config, file => File, problems => element(3, Reason)}),
                    refuse_boot(Reason)
            end
    end.

-spec stop(term()) -> ok.
stop(_State) ->
    ok.

%% While the boot script starts the release's applications (its progress
%% is applications_loaded until they all run), a refused start would take
%% the node down with "Kernel pid terminated" and an erl_crash.dump: the
%% mistakes are said, so stop there with status 1. Started otherwise (a
%% test node, application:start/1), the caller gets the error.
refuse_boot(Reason) ->
    case init:get_status() of
        {starting, applications_loaded} ->
            _ = logger_std_h:filesync(default),
            erlang:halt(1);
        _ ->
            {error, Reason}
    end.

listeners(#{listeners := undefined}) -> from_environment;
listeners(#{listeners := Ls}) -> length(Ls).
