%% @doc Internal. The supervisor of evatar_web: the WoT consumers, the event
%% streams' admission and the HTTP server (ranch's embedded listener running
%% cowboy, evatar_web_server), all absent when the environment's `enabled'
%% is false. The server is `permanent' with a low
%% intensity: a listener that cannot open (the port taken, a bad address)
%% stops the application's start with the reason, like the bridge's.
-module(evatar_web_sup).
-behaviour(supervisor).

-export([start_link/0, init/1]).

-spec start_link() -> {ok, pid()} | {error, term()}.
start_link() ->
    supervisor:start_link({local, ?MODULE}, ?MODULE, []).

%% @private
-spec init([]) -> {ok, {supervisor:sup_flags(), [supervisor:child_spec()]}}.
init([]) ->
    Children = case application:get_env(evatar_web, enabled, true) of
                   true ->
                       %% The event streams' admission (evatar_web_events).
                       %% The WoT consumers (docs/wot.md).
                       [#{id => evatar_web_things_sup,
                          start => {evatar_web_things_sup, start_link, []},
                          type => supervisor},
                        #{id => evatar_web_streams,
                          start => {evatar_web_streams, start_link, []}},
                        #{id => evatar_web_server,
                          start => {evatar_web_server, start_link, []},
                          type => supervisor,
                          restart => permanent}];
                   _ ->
                       []
               end,
    {ok, {#{strategy => one_for_one, intensity => 3, period => 10}, Children}}.
